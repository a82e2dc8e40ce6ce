"""The steps after the blocks are valid (thicker layers, junction centres, half-planes,
wall-fold relief) only improve a valid structure: a trial placement of theirs that cannot
be built (a section that finds no wall, as a first section moved along a branch beside
another vessel did in generated g0017) leaves the structure as it was, never fails it."""

from __future__ import annotations

import numpy as np

from junction_cases import bifurcation
from vmesh.errors import MeshingError
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.blocks.repair import _Repair


def test_a_wall_fold_trial_that_cannot_be_built_keeps_the_valid_blocks(monkeypatch):
    case = bifurcation(60, 1)
    kept = build_blocks(case.skeleton, case.distance, None, BlockOptions(relieve_wall_folds=False), project=case.project)

    def unbuildable(self, blocks):
        # a trial that changes the placement, then meets a section without wall
        for br in self.topo.branches:
            br.margin += 1.0
        self._apply_clearance()
        self.assemble()
        raise MeshingError("cross-section at skeleton node 1 finds no wall within reach")

    monkeypatch.setattr(_Repair, "relieve_wall_folds", unbuildable)
    blocks = build_blocks(case.skeleton, case.distance, None, BlockOptions(), project=case.project)
    assert blocks.corner_jacobians().min() > 0
    assert any("could not be built" in f for f in blocks.info["fixes"])
    assert np.array_equal(blocks.hexes, kept.hexes) and np.allclose(blocks.vertices, kept.vertices)
