"""Short closed side branches (an aneurysm sac beside a junction, issue 17 group C).

A closed branch that ends about two junction radii from its junction (the generator's
``aneurysm_side`` next to a ``radius_jump``: g0008 extracted, junction 17) leaves no room
between the junction's half cross-sections and the closed end's section: the sections
between them stayed at their nodes, inside the half-sections, and their blocks inverted
whatever the fixes did. Now the dome's retreat gives way to the junction first, and the
sections between stand between the half-sections' reach and the end section
(:meth:`vmesh.geometry.blocks.sections._Sections._apply_clearance`).
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import side_sac
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks

#: the default chain's resolution (as ``blocks.checks.FILL_CHECKS``)
DEFAULT_FILL = Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02)


def _build(*args):
    case, caps = side_sac(*args)
    blocks = build_blocks(case.skeleton, case.distance, caps, BlockOptions(), project=case.project, warn=lambda m: None)
    return case, blocks


@pytest.mark.parametrize("args", [(62, 1.4, 2.1, 0.75), (62, 1.0, 2.1, 0.75), (70, 1.3, 2.0, 0.7), (90, 1.4, 2.1, 0.75), (62, 1.4, 2.6, 0.75)])
def test_short_closed_side_branch_keeps_its_blocks(args):
    """Valid blocks with the sac kept (no skeleton change, its end closed by a dome: no
    boundary beyond the parent's two caps), the sac's sections in order along it."""
    case, blocks = _build(*args)
    assert blocks.corner_jacobians().min() > 0
    assert blocks.info.get("skeleton") is None or blocks.info["skeleton"].n_nodes == case.skeleton.n_nodes
    assert sorted(set(blocks.boundary_names.values())) == ["inlet", "outlet_1", "wall"]
    assert not blocks.info["cut_stubs"]


@pytest.mark.parametrize("args", [(62, 1.4, 2.1, 3.0), (60, 0.8, 2.0, 3.0)])
def test_one_segment_closed_side_branch_keeps_its_blocks(args):
    """A short closed side branch whose skeleton is one segment (as seed 1 g0009 given's
    junction 10: a closed stub 2.5 of its radii long): its dome's section, the branch's only
    one, stood back from the end inside the junction's half-sections (8-10 blocks at -1.5
    to -2.4) because the dome's retreat gave way only on branches with sections between.
    Now it gives way there too; the raw fill has no inverted element."""
    case, blocks = _build(*args)
    (junction,) = np.flatnonzero(case.skeleton.degrees == 3)
    assert case.skeleton.degrees[-1] == 1 and case.skeleton.edges[-1].tolist() == [junction, case.skeleton.n_nodes - 1]
    assert blocks.corner_jacobians().min() > 0
    assert blocks.info.get("skeleton") is None or blocks.info["skeleton"].n_nodes == case.skeleton.n_nodes
    assert sorted(set(blocks.boundary_names.values())) == ["inlet", "outlet_1", "wall"]
    assert not blocks.info["cut_stubs"]
    sm = mesh_blocks(blocks, case.project, DEFAULT_FILL, signed_distance=case.distance)
    assert scaled_jacobian(sm.points, sm.cells, DEFAULT_FILL.order).min() >= 0.3


def test_short_closed_side_branch_fills_valid():
    """The raw fill (no untangling) at the default chain's resolution: no inverted element,
    least scaled Jacobian at least 0.3."""
    case, blocks = _build(62, 1.4, 2.1, 0.75)
    sm = mesh_blocks(blocks, case.project, DEFAULT_FILL, signed_distance=case.distance)
    assert scaled_jacobian(sm.points, sm.cells, DEFAULT_FILL.order).min() >= 0.3


def test_long_closed_side_branch_keeps_its_dome_retreat():
    """A sac with room (6 radii) keeps its end section back from the dome."""
    case, blocks = _build(62, 1.0, 6.0, 0.75)
    assert blocks.corner_jacobians().min() > 0
    assert max(blocks.info["dome_retreat"].values()) > 0



def _closed_past_branch(keep: float):
    from junction_cases import closed_end_past_branch
    from vmesh.geometry.blocks.options import EndOptions

    case, caps = closed_end_past_branch(gap=1.0, angle=90.0, ratio=0.6)
    return case, build_blocks(case.skeleton, case.distance, caps, BlockOptions(ends=EndOptions(dome_keep=keep)), project=case.project, warn=lambda m: None)


def test_closed_end_one_radius_past_a_junction_keeps_a_dome_with_dome_keep():
    """A vessel that ends closed one radius past the junction where a side branch leaves,
    its skeleton run to the dome's tip (seed 0 g0000 given's outlet 76): the junction's
    half-sections take the dome's room and, by default, its section goes onto the
    endpoint, where the cap of blocks round the dome has no height (a raw fill Jacobian
    ratio of 0.005). ``dome_keep`` keeps the section off the endpoint (a dome of 0.1
    radii) and the fill's least Jacobian ratio above 0.1."""
    from vmesh.geometry.quality import jacobian_ratio

    _, blocks = _closed_past_branch(0.0)
    end = max(blocks.info["dome_retreat"])
    assert blocks.info["dome_retreat"][end] == 0.0
    case, blocks = _closed_past_branch(0.3)
    assert blocks.corner_jacobians().min() > 0
    assert blocks.info["dome_retreat"][end] > 0.05
    sm = mesh_blocks(blocks, case.project, DEFAULT_FILL, signed_distance=case.distance)
    assert jacobian_ratio(sm.points, sm.cells, DEFAULT_FILL.order).min() > 0.1
