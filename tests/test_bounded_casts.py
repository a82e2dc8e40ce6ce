"""Bounded work in the casts before the block builder (issue 17, "every stage has work
bounded by the input size"): the march evaluates the far half of its first batch only
for rays that need it, and the bend thinning casts a segment's ray once, not once per
round (the BraVa tree's resampling cast 30,143 rays for 4,014 distinct ones)."""

from __future__ import annotations

import numpy as np
import pytest

from test_blocks import capsule_distance
from vmesh.geometry import rays as rays_mod
from vmesh.geometry.cross_sections import unit
from vmesh.geometry.rays import RayCache, cast_rays
from vmesh.geometry.skeleton.bends import section_gaps, thin_sharp_bends
from vmesh.geometry.skeleton_ops import resample_skeleton
from vmesh.skeleton import Skeleton


def counted(distance):
    """``distance`` and a list whose first item counts the points it was asked about."""
    n = [0]

    def f(p):
        n[0] += len(np.asarray(p).reshape(-1, 3))
        return distance(p)

    return f, n


def axis_rays(m: int, seed: int = 0):
    """``m`` rays from the axis of a capsule along x (radius 1) in random perpendicular directions."""
    rng = np.random.default_rng(seed)
    o = np.c_[rng.uniform(2.0, 8.0, m), np.zeros((m, 2))]
    d = unit(np.c_[np.zeros(m), rng.standard_normal((m, 2))])
    return o, d


def zigzag(corners: int, arm: float = 8.0):
    """A tube (radius 1) of ``corners + 1`` straight arms, turning by 140, -70, -140, 70
    degrees in turn (sharp corners the thinning drops nodes at, gentle ones it only
    checks by a cast), resampled at 1.25 radii, and its signed distance."""
    turns = np.radians([140.0, -70.0, -140.0, 70.0])
    P, heading = [np.zeros(3)], 0.0
    for k in range(corners + 1):
        P.append(P[-1] + arm * np.array([np.cos(heading), np.sin(heading), 0.0]))
        heading += turns[k % 4]
    P = np.asarray(P)
    sk = Skeleton(P, np.ones(len(P)), np.c_[np.arange(len(P) - 1), np.arange(1, len(P))])
    return resample_skeleton(sk, 1.25), capsule_distance(P[:-1], P[1:], np.ones(len(P) - 1))


def test_march_looks_past_its_first_samples_only_for_rays_still_inside(monkeypatch):
    dist = capsule_distance(np.array([[0.0, 0, 0]]), np.array([[10.0, 0, 0]]), np.array([1.0]))
    o, d = axis_rays(100)
    f, n = counted(dist)
    # the wall one radius out: 5 march steps of 0.2, within the first 6 samples
    near = cast_rays(f, o, d, np.ones(100), iterations=24)
    assert np.allclose(near, 1.0, atol=1e-6)
    assert n[0] == 100 * (1 + 6 + 24)  # origins, the first 6 samples, the bisection
    # the wall 10 steps out: those rays evaluate the other 6 samples of the batch too
    n[0] = 0
    far = cast_rays(f, o, d, np.full(100, 0.5), iterations=24)
    assert np.allclose(far, 1.0, atol=1e-6)
    assert n[0] == 100 * (1 + 12 + 24)
    # the same samples as a march that evaluates the whole batch at once, so the same walls
    rng = np.random.default_rng(3)
    scale = rng.uniform(0.05, 2.0, 100)
    split = cast_rays(dist, o, d, scale, reach=30.0)
    monkeypatch.setattr(rays_mod, "_FIRST_SAMPLES", 12)
    assert np.array_equal(split, cast_rays(dist, o, d, scale, reach=30.0), equal_nan=True)


def test_rays_of_one_section_ask_about_their_shared_centre_once():
    dist = capsule_distance(np.array([[0.0, 0, 0]]), np.array([[10.0, 0, 0]]), np.array([1.0]))
    centres = np.c_[np.linspace(2.0, 8.0, 10), np.zeros((10, 2))]
    ang = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    d = np.stack([np.zeros(8), np.cos(ang), np.sin(ang)], axis=1)
    o = np.repeat(centres, 8, axis=0)  # as the block builder repeats a section's centre
    f, n = counted(dist)
    walls = cast_rays(f, o, np.tile(d, (10, 1)), np.ones(80), iterations=24)
    assert np.allclose(walls, 1.0, atol=1e-6)
    assert n[0] == 10 + 80 * (6 + 24)


@pytest.mark.parametrize("corners", [3, 6])
def test_bend_thinning_casts_only_around_the_nodes_it_drops(corners):
    sk, dist = zigzag(corners)
    gap, _, _ = section_gaps(sk)
    r = np.maximum(sk.radii[sk.edges[:, 0]], sk.radii[sk.edges[:, 1]])
    suspect = int(np.sum(gap < 6.0 * r))  # the first round casts these (reach 6 radii)
    cache = RayCache()
    thinned, removed = thin_sharp_bends(sk, 1.0, dist, rays=cache)
    assert removed > 0 and thinned.n_nodes == sk.n_nodes - removed
    # a dropped node changes the planes of its bridge and of the two segments beside it:
    # every later round casts at most those; the rest comes from the cache
    assert suspect <= cache.misses <= suspect + 3 * removed
    assert cache.hits > 0
    # a cache shared with another call answers every ray of the same skeleton
    again, removed_again = thin_sharp_bends(sk, 1.0, dist, rays=cache)
    assert removed_again == removed and np.array_equal(again.points, thinned.points)
    assert cache.misses <= suspect + 3 * removed


def test_bend_thinning_work_grows_with_the_corners_not_faster():
    work = {}
    for corners in (4, 8):
        sk, dist = zigzag(corners)
        cache = RayCache()
        _, removed = thin_sharp_bends(sk, 1.0, dist, rays=cache)
        work[corners] = (cache.misses, removed)
    # twice the corners: twice the rays and dropped nodes, give or take the two end arms
    assert work[8][1] <= 2 * work[4][1] + 2
    assert work[8][0] <= 2 * work[4][0] + 8


def test_the_casts_keep_their_old_names():
    from vmesh.geometry import cross_sections as cs
    from vmesh.geometry.blocks import work

    assert cs.cast_rays is cast_rays and cs.RayCache is RayCache and work.RayCache is RayCache
