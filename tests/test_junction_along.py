"""Along-skeleton block edges at junctions (issue 18): the turns the edges of one block ask
for are averaged over the blocks they share before the bound that keeps a block's edges
bending alike (:mod:`vmesh.geometry.transfinite_curves`).

Next to a junction's spine the edges of one block ask for turns towards different sides
(each from its own half-plane towards the branch). Bounded edge by edge, the bound scaled
the ICA's crotch edges down to 5-30 % of their turn and its crotch elements stayed sheared
at the half-plane (raw least scaled Jacobian 0.335); averaged first, they keep most of it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from junction_cases import bifurcation
from test_junctions import DEFAULT, build, fill
from vmesh.blocks import AXIS_ALONG
from vmesh.geometry import transfinite_curves as curves
from vmesh.geometry.transfinite_lattice import block_topology

CURVED = dataclasses.replace(DEFAULT, curved_sections=True)


@pytest.fixture(scope="module")
def bif_30_1():
    case = bifurcation(30, 1)
    return case, build(case)


def _bulges(blocks, monkeypatch=None):
    """Mid-point offsets of the along edges from their chords, the topology and the curved mask."""
    topo = block_topology(blocks)
    V = blocks.vertices
    tangent, curved = curves.along_tangents(blocks, topo, V)
    L = np.linalg.norm(V[topo.edges[:, 1]] - V[topo.edges[:, 0]], axis=1)
    bulge = (L / 8.0)[:, None] * (tangent[:, 0] - tangent[:, 1])
    bulge[~curved] = 0.0
    return bulge, topo, curved


def _along_edges(blocks, topo):
    along = blocks.axis_kind == AXIS_ALONG
    b = np.flatnonzero(along.sum(axis=1) == 1)
    a = np.argmax(along[b], axis=1)
    return b, topo.block_edge[b[:, None], 4 * a[:, None] + np.arange(4)]


@pytest.mark.slow
def test_along_edges_of_a_block_bend_alike(bif_30_1):
    """Any two along edges of a block: their mid-point offsets differ by at most ALIKE
    times their distance (the bound that keeps thin blocks unfolded), and the edges next to
    the junction still turn (the crotch's edges are not scaled down to nothing)."""
    case, blocks = bif_30_1
    bulge, topo, curved = _bulges(blocks)
    b, E = _along_edges(blocks, topo)
    V = blocks.vertices
    M = 0.5 * (V[topo.edges[E, 0]] + V[topo.edges[E, 1]])
    gap = np.linalg.norm(M[:, :, None] - M[:, None, :], axis=3)
    diff = np.linalg.norm(bulge[E][:, :, None] - bulge[E][:, None, :], axis=3)
    assert np.all(diff <= curves.ALIKE * gap * (1 + 1e-6) + 1e-12)
    # the blocks at the junction's spine (vertices of three segments' blocks): their edges
    # still turn by a fair angle (bounded edge by edge they turned by 1-9 degrees on the ICA)
    L = np.linalg.norm(V[topo.edges[:, 1]] - V[topo.edges[:, 0]], axis=1)
    turn = np.degrees(np.arcsin(np.clip(4 * np.linalg.norm(bulge, axis=1) / np.maximum(L, 1e-300), 0, 1)))
    segs = np.zeros((len(V), blocks.block_segment.max() + 1), bool)
    segs[blocks.hexes.ravel(), np.repeat(blocks.block_segment, 8)] = True
    spine = segs.sum(axis=1) >= 3
    at_spine = spine[blocks.hexes[b]].any(axis=1)
    assert at_spine.sum() >= 8
    assert np.median(turn[E[at_spine]]) >= 8.0


@pytest.mark.slow
@pytest.mark.parametrize("angle,ratio", [(30, 1), (15, 1)])
def test_averaged_bulges_fill_better_at_the_crotch(angle, ratio, monkeypatch):
    """The raw fill (curved sections, no untangling) of a narrow bifurcation is valid and
    better with the bulges averaged than bounded edge by edge (numbers in docs/junctions.md)."""
    case = bifurcation(angle, ratio)
    blocks = build(case)
    # duplicates: the same A/B check as test_junctions' curved-edge test, on another switch
    averaged = fill(case, blocks, CURVED)
    monkeypatch.setattr(curves, "SMOOTH_ROUNDS", 0)
    alone = fill(case, blocks, CURVED)
    assert averaged.min() > 0
    assert averaged.min() >= alone.min() + 0.02, f"{alone.min():.3f} -> {averaged.min():.3f}"
    assert averaged.mean() >= alone.mean() - 1e-3


def test_no_bulge_in_a_straight_tube():
    """Averaging keeps a straight tube's along edges straight."""
    from cylinder_blocks import cylinder_blocks

    bulge, _, curved = _bulges(cylinder_blocks())
    assert not curved.any() and np.abs(bulge).max() == 0.0
