"""Skeleton cleaning steps that run in one place only (issue 20)."""

from __future__ import annotations

import numpy as np

from test_skeleton_fit import context, vessel
from vmesh.registry import get_filter
from vmesh.skeleton import Skeleton


def _with_far_piece(factor: float = 1.5) -> Skeleton:
    """The true y_bifurcation skeleton plus a straight piece of ``factor`` x its node count
    far outside the surface (the centerline of a surface piece that was not meshed)."""
    _, _, truth = vessel()
    n = int(factor * truth.n_nodes)
    far = truth.points.max(axis=0) + np.array([0.0, 0.0, 50.0]) + np.c_[np.arange(n), np.zeros(n), np.zeros(n)]
    edges = np.c_[np.arange(n - 1), np.arange(1, n)] + truth.n_nodes
    return Skeleton(np.r_[truth.points, far], np.r_[truth.radii, np.ones(n)], np.r_[truth.edges, edges])


def _drop_warnings(ctx) -> list[str]:
    return [w for w in ctx.report.warnings if "lying outside the surface" in w]


def test_pieces_outside_are_dropped_once_by_estimate_radii_then_clean_skeleton():
    _, _, truth = vessel()
    ctx = context(_with_far_piece())
    get_filter("estimate_radii")(ctx)
    assert ctx.skeleton.n_nodes == truth.n_nodes and len(_drop_warnings(ctx)) == 1
    get_filter("clean_skeleton")(ctx)
    assert len(_drop_warnings(ctx)) == 1  # clean_skeleton does not look again
    assert ctx.skeleton.n_components == 1


def test_clean_skeleton_alone_drops_pieces_outside_before_judging_the_fit():
    # the far piece has more nodes than the vessel's: judged first, the fit would fail
    # ("60 % of centerline nodes lie outside the surface")
    ctx = context(_with_far_piece())
    get_filter("clean_skeleton")(ctx)
    assert len(_drop_warnings(ctx)) == 1 and "skeleton_fit" in ctx.report.sections
    assert ctx.skeleton.n_components == 1
    assert (vessel()[1].distance(ctx.skeleton.points) > -1e-6).all()


# ---------------------------------------------------------------------------
# spur pruning: one selection rule for the extraction's branch graph and for arrays
# ---------------------------------------------------------------------------


def test_select_spurs_takes_the_lowest_first_and_leaves_each_junction_two_branches():
    from vmesh.geometry.skeleton.clean import select_spurs

    degree = {7: 3, 8: 4}
    assert select_spurs([0.5, 0.2, 0.9, 0.1, 0.3], [7, 7, 8, 8, 8], degree) == [3, 1, 4]
    assert select_spurs([], [], degree) == []


def _star(lengths, radius=1.0, step=0.25):
    """A junction at the origin with straight branches of ``lengths`` along the
    directions of a regular polygon in the xy plane: ``(BranchGraph, Skeleton)``."""
    from vmesh.geometry.skeleton.branch_graph import BranchGraph

    graph = BranchGraph()
    centre = graph.add_node([0.0, 0, 0], radius)
    points, edges = [[0.0, 0, 0]], []
    for k, length in enumerate(lengths):
        d = np.array([np.cos(2 * np.pi * k / len(lengths)), np.sin(2 * np.pi * k / len(lengths)), 0.0])
        s = np.arange(step, length + 1e-9, step)
        tip = graph.add_node(length * d, radius)
        graph.add_branch(centre, tip, s[:-1, None] * d, np.full(len(s) - 1, radius))
        first = len(points)
        points += (s[:, None] * d).tolist()
        edges += [[0, first]] + [[first + i, first + i + 1] for i in range(len(s) - 1)]
    return graph, Skeleton(np.array(points), np.full(len(points), radius), np.array(edges))


def test_both_cleanings_prune_two_spurs_of_a_four_way_junction_and_keep_the_vessel():
    from vmesh.geometry.skeleton.clean import remove_spurs

    graph, skel = _star([10.0, 0.5, 10.0, 0.75])
    assert graph.prune_spurs(2.0) == 2
    assert graph.graph.number_of_nodes() == 2 and graph.graph.number_of_edges() == 1  # one straight vessel
    cleaned, removed = remove_spurs(skel, 1.0)
    assert removed == 2 and len(cleaned.junctions) == 0 and len(cleaned.endpoints) == 2


def test_both_cleanings_keep_one_daughter_of_a_short_bifurcation():
    from vmesh.geometry.skeleton.clean import remove_spurs

    graph, skel = _star([10.0, 0.5, 0.75])
    assert graph.prune_spurs(2.0) == 1
    assert graph.graph.number_of_edges() == 1
    ends = sorted(float(np.linalg.norm(graph.pos(n))) for n in graph.graph.nodes)
    np.testing.assert_allclose(ends, [0.75, 10.0])  # the shorter, least salient spur went
    cleaned, removed = remove_spurs(skel, 1.0)
    assert removed == 1 and len(cleaned.endpoints) == 2
    np.testing.assert_allclose(sorted(np.linalg.norm(cleaned.points[cleaned.endpoints], axis=1)), [0.75, 10.0])
