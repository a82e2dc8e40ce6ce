"""Centerline defects of real vessels that the skeleton cleaning must undo before the block
builder sees them: repeated points (two branches leaving a junction along one segment, zero-length
segments), a second path inside a vessel leaving a junction a few degrees from it, and tiny loops
at a junction. Each is planted in a synthetic vessel whose true skeleton is known."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import synthetic_case
from vmesh.chain import FilterChain
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.skeleton.defects import weld_coincident_nodes
from vmesh.io.skeleton import read_skeleton
from vmesh.skeleton import Skeleton


def y_truth() -> Skeleton:
    surface, skeleton = synthetic_case("y_bifurcation")
    if not skeleton.exists():
        pytest.skip("synthetic case y_bifurcation not generated (python data_synthetic/generate.py)")
    return read_skeleton(skeleton)


def y_with_duplicate_start(gt: Skeleton) -> Skeleton:
    """The Y's second daughter starts on a copy of the junction node (as SWC files do): the
    parent's last node has two branches along one segment, 0 degrees apart."""
    c = int(np.flatnonzero(gt.degrees >= 3)[0])
    nb = gt.neighbors(c)
    parent = int(nb[np.argmax(gt.radii[nb])])
    daughter = int([n for n in nb if n != parent][1])
    n = gt.n_nodes
    keep = ~(np.sort(gt.edges, axis=1) == np.sort([c, daughter])).all(axis=1)
    edges = np.r_[gt.edges[keep], [[parent, n], [n, daughter]]]
    return Skeleton(np.r_[gt.points, gt.points[c : c + 1]], np.r_[gt.radii, gt.radii[c]], edges, name=gt.name)


def blocks_of(skeleton: Skeleton):
    """Run the default chain through build_block_structure on the Y surface with ``skeleton``."""
    steps = list(FilterChain.load("default"))
    k = [s.filter for s in steps].index("build_block_structure") + 1
    return FilterChain(steps[:k]).run(surface=synthetic_case("y_bifurcation")[0], skeleton=skeleton)


def test_weld_joins_repeated_points_into_the_real_junction():
    gt = y_truth()
    dup = y_with_duplicate_start(gt)
    assert dup.summary()["junctions"] == 1 and dup.n_nodes == gt.n_nodes + 1
    out, n = weld_coincident_nodes(dup)
    assert n == 1 and out.n_nodes == gt.n_nodes
    assert out.summary()["junctions"] == 1 and out.summary()["endpoints"] == 3
    j = np.flatnonzero(out.degrees >= 3)[0]
    np.testing.assert_allclose(out.points[j], gt.points[gt.degrees >= 3][0])
    assert ops.edge_lengths(out.points, out.edges).min() > 0
    # a zero-length segment inside a branch goes too; distinct nodes stay
    line = Skeleton([[0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0]], np.ones(4), [[0, 1], [1, 2], [2, 3]])
    out, n = weld_coincident_nodes(line)
    assert n == 1 and out.n_edges == 2 and ops.edge_lengths(out.points, out.edges).min() == 1
    same, n = weld_coincident_nodes(gt)
    assert n == 0 and same.n_nodes == gt.n_nodes


def test_blocks_build_when_two_branches_share_their_first_segment():
    ctx = blocks_of(y_with_duplicate_start(y_truth()))
    sk = ctx.skeleton
    assert sk.summary()["junctions"] == 1 and sk.summary()["endpoints"] == 3
    assert ctx.blocks is not None and len(ctx.blocks.hexes) > 0


def test_spur_inside_a_sibling_goes_whatever_its_length():
    # junction at the origin, trunk along -x, daughters at +-45 degrees; a 2-radius spur
    # 6 degrees from the upper daughter, its end inside that daughter's lumen
    r = 1.0
    up, down = np.array([1.0, 1.0, 0]) / np.sqrt(2), np.array([1.0, -1.0, 0]) / np.sqrt(2)
    a = np.radians(45 + 6)
    spur_dir = np.array([np.cos(a), np.sin(a), 0.0])
    s = np.linspace(0, 8, 9)[1:, None]
    pts = np.r_[[[0, 0, 0]], -s * [1, 0, 0], s * up, s * down, np.linspace(0, 2, 5)[1:, None] * spur_dir]
    n = len(pts)
    chains = [np.r_[0, 1 + np.arange(8)], np.r_[0, 9 + np.arange(8)], np.r_[0, 17 + np.arange(8)], np.r_[0, 25 + np.arange(4)]]
    edges = np.concatenate([np.c_[c[:-1], c[1:]] for c in chains])
    skel = Skeleton(pts, np.full(n, r), edges)
    out, k = ops.remove_spurs(skel, 1.0)
    assert k == 1 and out.n_nodes == n - 4 and out.summary()["endpoints"] == 3
    # protected (near a cap) does not save it either; a spur as long leaving 40 degrees off stays
    prot = np.zeros(n, bool)
    prot[-1] = True
    assert ops.remove_spurs(skel, 1.0, prot)[1] == 1
    a = np.radians(45 + 40)
    wide = skel.copy(points=np.r_[pts[:25], np.linspace(0, 2, 5)[1:, None] * [np.cos(a), np.sin(a), 0]])
    assert ops.remove_spurs(wide, 1.0)[1] == 0
    assert ops.remove_spurs(skel, 1.0, shadow=0.0)[1] == 0


def test_blocks_build_with_a_spur_along_a_daughter():
    gt = y_truth()
    c = int(np.flatnonzero(gt.degrees >= 3)[0])
    nb = gt.neighbors(c)
    daughter = int([n for n in nb if gt.radii[n] < gt.radii[c]][0])
    rc = float(gt.radii[c])
    d = gt.points[daughter] - gt.points[c]
    d /= np.linalg.norm(d)
    # 6 degrees off the daughter in the plane of the Y, two radii long
    axis = np.cross(d, [0, 0, 1.0])
    t = np.radians(6)
    e = np.cos(t) * d + np.sin(t) * axis
    tip = gt.points[c] + np.linspace(0, 2 * rc, 5)[1:, None] * e
    n = gt.n_nodes
    edges = np.r_[gt.edges, [[c, n]], np.c_[n + np.arange(3), n + 1 + np.arange(3)]]
    skel = Skeleton(np.r_[gt.points, tip], np.r_[gt.radii, np.full(4, gt.radii[daughter])], edges)
    ctx = blocks_of(skel)
    assert ctx.skeleton.summary()["endpoints"] == 3 and ctx.skeleton.summary()["junctions"] == 1
    assert len(ctx.blocks.hexes) > 0


def test_loop_narrower_than_the_vessel_collapses_into_its_junction():
    gt = y_truth()
    c = int(np.flatnonzero(gt.degrees >= 3)[0])
    rc = float(gt.radii[c])
    n = gt.n_nodes

    def with_loop(size):
        ring = gt.points[c] + size * rc * np.array([[0.3, 0.0, 1.0], [-0.3, 0.0, 1.0]])
        edges = np.r_[gt.edges, [[c, n], [n, n + 1], [n + 1, c]]]
        return Skeleton(np.r_[gt.points, ring], np.r_[gt.radii, [rc, rc]], edges)

    out, _ = ops.merge_close_junctions(with_loop(0.8), 0.5)
    assert out.n_nodes == n and out.summary()["cycles"] == 0
    kept, _ = ops.merge_close_junctions(with_loop(3.0), 0.5)  # a ring wider than the vessel stays
    assert kept.n_nodes == n + 2 and kept.summary()["cycles"] == 1


def _capsules_sdf(a, b, c, r):
    """Signed distance (positive inside, exact off the joint) of an L-shaped tube a-b-c of radius r."""

    def seg(p, u, v):
        d = v - u
        t = np.clip(((p - u) @ d) / (d @ d), 0, 1)
        return np.linalg.norm(p - (u + t[:, None] * d), axis=1)

    return lambda p: r - np.minimum(seg(np.atleast_2d(p), a, b), seg(np.atleast_2d(p), b, c))


def test_march_follows_a_bent_vessel_from_its_cap_to_the_skeleton():
    """A thin vessel the thinning missed, bending 90 degrees: no straight line from the
    skeleton to its cap stays inside; the march along its axis does."""
    from vmesh.geometry.skeleton.march import march_to_skeleton

    r = 0.5
    a, b, c = np.array([0.0, 0, 0]), np.array([6.0, 0, 0]), np.array([6.0, 8, 0])
    sdf = _capsules_sdf(a, b, c, r)
    # the skeleton: the far half of the second leg (a wider vessel would hold it)
    targets = b + np.linspace(0.5, 1.0, 11)[:, None] * (c - b)
    path, k = march_to_skeleton(sdf, a, np.array([1.0, 0, 0]), r, targets, np.full(len(targets), r))
    assert (sdf(path) > 0).all()
    axis_gap = np.minimum(np.hypot(path[:, 1], path[:, 2]), np.hypot(path[:, 0] - 6.0, path[:, 2]))
    assert axis_gap.max() < 0.35 * r  # on the axis of one leg or the other
    assert np.linalg.norm(path[-1] - targets[k]) < r
    assert path[:, 1].max() > 3.0  # went round the bend
    # a straight line from the skeleton point to the cap leaves the vessel
    line = targets[k] + np.linspace(0, 1, 50)[:, None] * (a - targets[k])
    assert (sdf(line) < 0).any()
    # a march into a dead end (no skeleton within reach) fails
    assert march_to_skeleton(sdf, a, np.array([1.0, 0, 0]), r, np.array([[40.0, 40, 40]]), np.array([r]), max_length=30) is None


def _acute_branch(angle: float = 10.0, parent_radius: float = 1.2, radius: float = 0.5, step: float = 0.2):
    """A parent vessel along x and a daughter leaving it at ``angle`` degrees from the
    junction at the origin (generated g0007's node 2: 10 degrees): the signed distance of
    the two tubes (positive inside) and their true skeleton."""
    d = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
    s_parent, s_daughter = np.arange(-10.0, 20.0 + 1e-9, step), np.arange(step, 20.0 + 1e-9, step)
    pts = np.r_[s_parent[:, None] * [1.0, 0.0, 0.0], s_daughter[:, None] * d]
    n_p, j = len(s_parent), int(np.argmin(np.abs(s_parent)))
    edges = np.r_[np.c_[np.arange(n_p - 1), np.arange(1, n_p)], [[j, n_p]], np.c_[np.arange(n_p, len(pts) - 1), np.arange(n_p + 1, len(pts))]]
    radii = np.r_[np.full(n_p, parent_radius), np.full(len(s_daughter), radius)]

    def distance(p):
        p = np.asarray(p, float).reshape(-1, 3)
        along_p = np.clip(p[:, 0], -10.0, 20.0)
        in_p = parent_radius - np.linalg.norm(p - along_p[:, None] * [1.0, 0.0, 0.0], axis=1)
        along_d = np.clip(p @ d, 0.0, 20.0)
        in_d = radius - np.linalg.norm(p - along_d[:, None] * d, axis=1)
        return np.maximum(in_p, in_d)

    return Skeleton(pts, radii, edges), distance


def test_an_acute_branch_inside_its_parent_starts_where_their_lumens_part():
    """Generated g0007 (given skeleton), node 2: a daughter leaves its parent 10 degrees
    apart and runs inside the parent's lumen for several parent radii; the block builder
    refused the junction (two branches 10 degrees apart around its axis). The junction moves
    along the two branches to where they part by 60 degrees, farther than ``max_shift`` (4)
    radii since they share one lumen up to there, and no farther than the lumen they share."""
    sk, distance = _acute_branch()
    c = int(sk.junctions[0])
    moved, n = ops.separate_parallel_branches(sk, 30.0, 60.0, distance=distance)
    assert n == 1 and len(moved.junctions) == 1
    j = int(moved.junctions[0])
    # past four parent radii along the parent, still a quarter radius inside the shared lumen
    assert moved.points[j][0] > 4.0 * 1.2 and distance(moved.points[j : j + 1])[0] >= 0.25 * 1.2
    # its branches now leave it at least 30 degrees apart (the block builder's junctions take them)
    d = moved.points[moved.neighbors(j)] - moved.points[j]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos = d @ d.T
    assert np.degrees(np.arccos(np.clip(cos[np.triu_indices(3, 1)], -1, 1))).min() > 30.0
    # topology kept: one junction, three ends, every node inside
    assert len(moved.endpoints) == 3 and np.all(distance(moved.points) > 0)
    # without the signed distance nothing tells the shared lumen: the junction stays within max_shift
    same, n0 = ops.separate_parallel_branches(sk, 30.0, 60.0)
    assert n0 == 0 and np.allclose(same.points[int(same.junctions[0])], sk.points[c])


def test_an_acute_branch_that_leaves_its_parent_keeps_its_junction_near_the_carina():
    """A daughter 25 degrees off its parent leaves the shared lumen early: the junction moves
    no farther than the lumen the two share (its new place is inside by a quarter radius)."""
    sk, distance = _acute_branch(angle=25.0)
    moved, n = ops.separate_parallel_branches(sk, 30.0, 60.0, distance=distance)
    j = int(moved.junctions[0])
    assert n == 1 and distance(moved.points[j : j + 1])[0] > 0.25 * 1.2
    assert moved.points[j][0] < 4.0 * 1.2
