"""Bounded work in the block builder (issue 17, "no run hangs"): rays cast once per build,
one corner-Jacobian pass per assembly, and a budget of assemblies after which a structure
that cannot be made valid fails with the usual error instead of trying on."""

from __future__ import annotations

import numpy as np
import pytest

from test_blocks import capsule_distance
from test_robustness_regressions import tee
from vmesh.blocks import HEX_CORNERS, hex_corner_jacobians
from vmesh.errors import MeshingError
from vmesh.geometry import cross_sections as cs
from vmesh.geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
from vmesh.geometry.blocks.work import RayCache, WorkBudget
from vmesh.geometry.skeleton_ops import resample_skeleton
from vmesh.skeleton import Skeleton


def comb(n_side: int, stub: bool = False, spacing: float = 8.0):
    """A parent tube (radius 2) from (-12, 0, 0) through the origin to (12, 0, 0), turning
    there to run along -y with ``n_side`` side branches (radius 0.8, 7 long) leaving it at
    90 degrees on alternate sides every ``spacing``; resampled at 1.25 radii, and its
    signed distance. With ``stub`` a stub leaves the origin along +y that never leaves the
    parent's lumen (:func:`test_robustness_regressions.tee`: a junction no fix makes valid)."""
    pts = [[-12.0, 0, 0], [0.0, 0, 0], [12.0, 0, 0]] + [[12.0, -spacing * (k + 1), 0] for k in range(n_side + 1)]
    edges = [(k, k + 1) for k in range(n_side + 3)]
    radii = [2.0] * len(pts)
    for k in range(n_side):
        pts.append([12.0 + (7.0 if k % 2 == 0 else -7.0), -spacing * (k + 1), 0.0])
        edges.append((k + 3, len(pts) - 1))
        radii.append(0.8)
    if stub:
        pts.append([0.0, 2.6, 0.0])
        edges.append((1, len(pts) - 1))
        radii.append(0.75)
    P, R, E = np.asarray(pts), np.asarray(radii), np.asarray(edges)
    sk = resample_skeleton(Skeleton(P, R, E), 1.25)
    return sk, capsule_distance(P[E[:, 0]], P[E[:, 1]], R[E[:, 1]])


# ---------------------------------------------------------------------------
# kernels
# ---------------------------------------------------------------------------
def test_ray_cache_gives_the_cast_rays_and_casts_each_ray_once():
    dist = capsule_distance(np.zeros((1, 3)), np.array([[10.0, 0, 0]]), np.array([1.5]))
    rng = np.random.default_rng(1)
    o = np.c_[rng.uniform(1, 9, 200), rng.uniform(-0.5, 0.5, (200, 2))]
    d = cs.unit(rng.standard_normal((200, 3)))
    scale = rng.uniform(0.5, 2.0, 200)
    direct = cs.cast_rays(dist, o, d, scale)
    cache = RayCache()
    first = cache.cast(dist, o, d, scale)
    assert np.array_equal(first, direct, equal_nan=True)
    assert (cache.misses, cache.hits) == (200, 0)
    # the same rays again, shuffled and with new ones among them: only the new ones are cast
    again = np.r_[np.arange(200)[::-1], np.arange(0, 200, 2)]
    o2 = np.r_[o[again], o[:10] + 0.1]
    d2, s2 = np.r_[d[again], d[:10]], np.r_[scale[again], scale[:10]]
    out = cache.cast(dist, o2, d2, s2)
    assert np.array_equal(out, cs.cast_rays(dist, o2, d2, s2), equal_nan=True)
    assert (cache.misses, cache.hits) == (210, 300)
    # another reach is another ray
    cache.cast(dist, o[:5], d[:5], scale[:5], reach=3.0)
    assert cache.misses == 215


def test_ray_cache_stays_within_its_limit():
    dist = capsule_distance(np.zeros((1, 3)), np.array([[10.0, 0, 0]]), np.array([1.5]))
    cache = RayCache(limit=50)
    for k in range(4):
        o = np.c_[np.linspace(1, 9, 30) + 0.01 * k, np.zeros((30, 2))]
        cache.cast(dist, o, np.tile([0.0, 1.0, 0.0], (30, 1)), np.ones(30))
        assert len(cache) <= 50


def test_corner_jacobians_of_affine_and_flipped_blocks():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((50, 3, 3))
    corners = np.einsum("bij,cj->bci", A, HEX_CORNERS.astype(float)) + rng.standard_normal((50, 1, 3))
    J = hex_corner_jacobians(corners)
    assert J.shape == (50, 8)
    assert np.allclose(J, np.linalg.det(A)[:, None], rtol=1e-9, atol=1e-12)
    # a block flipped along k (what the assembly does to mirrored blocks) has the negated
    # Jacobians of its mirrored corners, bit for bit (the assembly keeps them so)
    perm = [4, 5, 6, 7, 0, 1, 2, 3]
    assert np.array_equal(hex_corner_jacobians(corners[:, perm]), -J[:, perm])


# ---------------------------------------------------------------------------
# the builder's work
# ---------------------------------------------------------------------------
@pytest.mark.slow  # four builds, about 4 s
def test_a_hopeless_junction_fails_in_assemblies_and_rays_bounded_by_the_tree():
    """A stub that never leaves its parent (no fix makes its blocks valid) on trees of 2
    and 6 further side branches: the build fails with the usual error after the same
    number of assemblies (within the budget) whatever the tree's size, and casts each
    section's rays about once, not once per assembly."""
    used = []
    for n_side in (2, 6):
        healthy = WorkBudget(160)
        blocks = build_blocks(*comb(n_side), None, BlockOptions(), work=healthy)
        assert block_structure_checks(blocks)["invalid_blocks"] == 0
        assert blocks.info["work"]["assemblies"] == healthy.used
        sk, dist = comb(n_side, stub=True)
        work = WorkBudget(BlockOptions().repair.work_budget)
        with pytest.raises(MeshingError, match=r"block\(s\) stay invalid"):
            build_blocks(sk, dist, None, BlockOptions(), work=work)
        assert 10 <= work.used <= work.limit
        assert work.rays.misses <= 2 * healthy.rays.misses < work.rays.hits
        used.append(work.used)
    assert used[0] == used[1]


def test_a_spent_budget_stops_the_build_saying_so():
    sk, dist = comb(2, stub=True)
    small = WorkBudget(5)
    with pytest.raises(MeshingError, match=r"stay invalid.*5 assemblies.*work_budget = 5"):
        build_blocks(sk, dist, None, BlockOptions(work_budget=5), work=small)
    assert small.used == 5
    # the option alone sets the budget
    sk, dist = tee(2.6)
    with pytest.raises(MeshingError, match="work_budget = 3"):
        build_blocks(sk, dist, None, BlockOptions(work_budget=3))


def test_territory_cut_is_kept_across_assemblies_and_gives_the_same_blocks(monkeypatch):
    """The section rays' territory cut (tubes, ways along the skeleton, each ray's cut) is
    kept by the builder while its skeleton stays as it is: a build with fix rounds reuses
    the cuts of the sections that did not move, and its blocks are bit for bit those of a
    build that clips every ray afresh on every assembly."""
    from junction_cases import bifurcation
    from vmesh.geometry import skeleton_ops as ops
    from vmesh.geometry.blocks.prep import Territory
    from vmesh.geometry.blocks.sections import _Sections

    case = bifurcation(15, 5)
    sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    kept = build_blocks(sk, case.distance, None, BlockOptions())
    work = kept.info["work"]
    assert work["assemblies"] > 1 and work["territory_reused"] > work["territory_cut"] > 0

    def fresh(self):
        self.topo.territory = Territory(self.topo.branches, self.topo.pos, self.topo.sk.radii, self.topo.sk.edges)
        return self.topo.territory

    monkeypatch.setattr(_Sections, "_territory", fresh)
    again = build_blocks(sk, case.distance, None, BlockOptions())
    assert again.info["work"]["territory_reused"] == 0
    assert np.array_equal(kept.vertices, again.vertices) and np.array_equal(kept.hexes, again.hexes)
    assert kept.info["fixes"] == again.info["fixes"]


def test_territory_cuts_far_from_a_moved_junction_are_kept_and_equal_fresh_ones():
    """A fix that moves a junction node changes the tubes and ways next to it only: the cuts
    of rays far from it are kept (:meth:`~vmesh.geometry.blocks.prep.Territory.inherit`),
    and every cut equals one found afresh on the moved skeleton."""
    from types import SimpleNamespace

    from test_touching_vessels import touching
    from vmesh.geometry import cross_sections as cs
    from vmesh.geometry.blocks.sections import _Sections
    from vmesh.geometry.blocks.state import _Topology
    from vmesh.geometry.rays import cast_rays
    from vmesh.geometry.skeleton.graph import branch_paths

    case, _, _ = touching(1.5)
    sk = case.skeleton

    class Cut(_Sections):
        def __init__(self, pos):
            self.opt = BlockOptions()
            self.topo = _Topology(sk)
            self.topo.pos = pos.copy()
            self.topo.branches = [SimpleNamespace(nodes=np.asarray(p)) for p in branch_paths(sk.n_nodes, sk.edges)]

        def cut(self):
            idx = [(b, k) for b, br in enumerate(self.topo.branches) for k in range(len(br.nodes))]
            node = np.array([self.topo.branches[b].nodes[k] for b, k in idx])
            origin, rad = self.topo.pos[node], sk.radii[node]
            e1 = cs.any_perpendicular(np.tile([0.3, 0.5, 0.8], (len(node), 1)) / np.linalg.norm([0.3, 0.5, 0.8]))
            ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
            e2 = np.cross(np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8]), e1)
            dirs = cs.ray_directions(e1, e2, ang)
            R = cast_rays(case.distance, np.repeat(origin, 8, axis=0), dirs.reshape(-1, 3), np.repeat(rad, 8)).reshape(len(node), 8)
            return R, self._own_territory(idx, origin, dirs, R, rad)

    kept = Cut(sk.points)
    R, first = kept.cut()
    assert np.isfinite(first).all() and np.any(first < R - 0.1)  # rays across the contact are cut
    moved = sk.points.copy()
    j = int(sk.junctions[0])
    moved[j] += 0.3 * sk.radii[j] * np.array([1.0, 0.0, 0.0])
    kept.topo.pos = moved
    hits = kept.topo.territory.cuts.hits
    again = kept.cut()[1]
    assert kept.topo.territory.cuts.hits > hits  # cuts far from the junction reused
    assert np.array_equal(again, Cut(moved).cut()[1])
