"""Side-branch stubs shorter than their junction's half cross-sections (issue 17).

The generator's ``stub`` feature cuts a side branch open one or two of its radii past its
parent's wall; ``thin_stubs`` leaves it one segment from the junction to its cap. When the
junction's half-sections reach as far along it as its cap, the blocks between the folded
end section and the cap section have no thickness and no fix can move a section: the
builder cuts the stub back into its parent (:mod:`vmesh.geometry.blocks.stubs`), warns and
records the cut; a stub with room for its blocks keeps them.
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import side_stub
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks

#: the default chain's resolution and a finer one (as ``blocks.checks.FILL_CHECKS``)
REFINEMENTS = (Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02),
               Refinement(around=4, core=3, ring=3, layer=4, element_length=0.25, first_layer=0.01))


def _build(*args):
    case, caps = side_stub(*args)
    warnings = []
    blocks = build_blocks(case.skeleton, case.distance, caps, BlockOptions(), project=case.project, warn=warnings.append)
    return case, blocks, warnings


@pytest.mark.parametrize("args", [(55, 0.3, 1.0), (50, 0.4, 1.0)])
def test_short_stub_is_cut_back_into_its_parent(args):
    """A stub that ends within its junction's half-sections: valid blocks without it, the cut
    named by its cap in a warning and in ``info['cut_stubs']``, the cap left out of the
    boundary names."""
    case, blocks, warnings = _build(*args)
    assert blocks.corner_jacobians().min() > 0
    cut = blocks.info["cut_stubs"]
    assert [s["cap"] for s in cut] == ["outlet_2"]
    assert cut[0]["length"] <= cut[0]["reach"] + BlockOptions().junction.junction_margin * cut[0]["radius"]
    assert any("cut the side branch" in w and "'outlet_2'" in w for w in warnings)
    assert "outlet_2" not in blocks.boundary_names.values()
    sk = blocks.info["skeleton"]
    assert len(sk.junctions) == 0 and sk.n_nodes == case.skeleton.n_nodes - 1
    # the parent keeps both its open ends
    assert {"inlet", "outlet_1"} <= set(blocks.boundary_names.values())


def test_cut_stub_mouth_is_named_not_wall():
    """The parent's wall faces over a cut stub's mouth are a cap ``stub_1`` of their own (a
    missing branch never shows as wall): only faces over the mouth, all of them within the
    stub's radius of its axis, and the wall elsewhere keeps its label."""
    case, blocks, _ = _build(55, 0.3, 1.0)
    stub = blocks.info["cut_stubs"][0]
    assert stub["boundary"] == "stub_1"
    fid = [k for k, v in blocks.boundary_names.items() if v == "stub_1"]
    assert len(fid) == 1
    quads, ids = blocks.boundary_quads()
    mouth = blocks.vertices[quads[ids == fid[0]]].mean(axis=1)
    a0, a1 = np.asarray(stub["start"]), np.asarray(stub["end_point"])
    ax = (a1 - a0) / np.linalg.norm(a1 - a0)
    t = (mouth - a0) @ ax
    assert len(mouth) >= 1 and np.all(np.linalg.norm(mouth - a0 - t[:, None] * ax, axis=1) < stub["radius"])
    assert np.count_nonzero(ids == 0) > 10 * len(mouth)


def test_cut_stub_fills_valid_at_every_refinement():
    """The parent without its stub fills with min scaled Jacobian >= 0.3 at the default and a
    finer resolution (no untangling)."""
    case, blocks, _ = _build(55, 0.3, 1.0)
    for ref in REFINEMENTS:
        sm = mesh_blocks(blocks, case.project, ref, signed_distance=case.distance)
        assert scaled_jacobian(sm.points, sm.cells, ref.order).min() >= 0.3


@pytest.mark.parametrize("args", [(90, 0.6, 2.0), (80, 0.6, 3.0)])
def test_stub_with_room_keeps_its_blocks(args):
    """A stub long enough for a block between its junction and its cap is not cut."""
    _, blocks, warnings = _build(*args)
    assert blocks.corner_jacobians().min() > 0
    assert blocks.info["cut_stubs"] == []
    assert "outlet_2" in blocks.boundary_names.values()
    assert not any("cut the side branch" in w for w in warnings)


def test_stub_cut_slant_at_its_parents_wall_is_cut_not_a_lost_section():
    """A thin stub (radius 0.12) cut open at its parent's wall by a plane 55 degrees off its
    axis (generated g0007 extracted: a 0.019 cm opening on a 0.07 vessel): its cap section
    lies in that plane, half inside the parent, and its rays run 12 stub radii through the
    parent's lumen without meeting the wall ("finds no wall within reach"). The stub is cut
    back into its parent instead, as any stub within its junction's half-sections."""
    case, blocks, warnings = _build(90, 0.12, 0.4, 8.0, 55)
    assert blocks.corner_jacobians().min() > 0
    assert [s["cap"] for s in blocks.info["cut_stubs"]] == ["outlet_2"]
    assert "outlet_2" not in blocks.boundary_names.values()
    assert any("cut the side branch" in w for w in warnings)
