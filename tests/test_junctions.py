"""Junction block structures over a sweep of generated bifurcations and trifurcations
(issue 18): every block valid, and the transfinite fill valid without any untangling.

The vessels are smooth unions of straight tubes (:mod:`junction_cases`): branch angles
15-170 degrees, radius ratios 1:1 to 1:5, daughters out of the plane, trifurcations and
two junctions a few radii apart. The skeleton goes through ``separate_parallel_branches``
as ``clean_skeleton`` does in the default chain. Configurations whose crotch still folds
are expected failures (strict: they must be unmarked once they pass).
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import bifurcation, close_junctions, trifurcation
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.block_builder import BlockOptions, build_blocks, fill_quality
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks

#: the default chain's element counts (mesh_transfinite defaults)
DEFAULT = Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02)


def build(case):
    sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    return build_blocks(sk, case.distance, None, BlockOptions(), project=case.project)


def fill(case, blocks, ref=DEFAULT):
    sm = mesh_blocks(blocks, case.project, ref, signed_distance=case.distance)
    return scaled_jacobian(sm.points, sm.cells, ref.order)
