"""Skeleton ends lying just outside a closed end (issue 17): ``pull_inside`` brings them
back along their branch to the last full cross-section behind the end, not up the signed
distance to a radius' depth (which left the mesh a radius or more short of a closed end
that no cap was found on)."""

from __future__ import annotations

import numpy as np
import pytest

from vmesh.geometry.skeleton.distance import pull_inside
from vmesh.skeleton import Skeleton

R, L = 1.0, 10.0


def closed_tube(rounded: bool):
    """Signed distance (positive inside) of a tube along z from 0 to ``L``, radius ``R``:
    a flat end face at z = L, or a hemisphere beyond it (tip at L + R)."""

    def distance(p):
        p = np.asarray(p, float).reshape(-1, 3)
        rho, z = np.linalg.norm(p[:, :2], axis=1), p[:, 2]
        if rounded:
            zc = np.clip(z, 0.0, L)
            d = R - np.hypot(rho, z - zc)
            return np.where(z < 0, np.minimum(d, z), d)
        dr, dz = rho - R, np.maximum(-z, z - L)
        outside = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0))
        return -(np.minimum(np.maximum(dr, dz), 0) + outside)

    return distance


def axis_skeleton(end_z: float, spacing: float = 0.3, junction_at: float | None = None) -> Skeleton:
    """Nodes on the axis from z = 1 to ``end_z``; with ``junction_at``, a side branch there."""
    z = np.arange(1.0, end_z, spacing)
    pts = np.c_[np.zeros((len(z), 2)), z]
    pts = np.vstack([pts, [0, 0, end_z]])
    edges = np.c_[np.arange(len(pts) - 1), np.arange(1, len(pts))]
    if junction_at is not None:
        j = int(np.argmin(np.abs(pts[:, 2] - junction_at)))
        pts = np.vstack([pts, [0.5 * R, 0, pts[j, 2] - 0.2]])
        edges = np.vstack([edges, [j, len(pts) - 1]])
    return Skeleton(pts, np.full(len(pts), R), edges)


def test_end_outside_a_flat_closed_end_stays_at_the_end_face():
    distance = closed_tube(rounded=False)
    skel = axis_skeleton(L + 0.13 * R)
    out, n_pulled, n_dropped = pull_inside(skel, distance)
    assert n_pulled == 1 and n_dropped == skel.n_nodes - out.n_nodes  # the nodes it went back past
    end = out.points[out.degrees == 1][np.argmax(out.points[out.degrees == 1, 2])]
    # before: up the signed distance to a radius' depth, z = L - R
    assert L - 0.3 * R < end[2] < L and np.hypot(*end[:2]) < 0.05 * R
    assert (distance(out.points) > 0).all()
    assert out.n_edges == out.n_nodes - 1 and (out.degrees <= 2).all()  # one chain still
    assert np.all(np.diff(out.points[:, 2]) > 0)  # no node left beyond the new end


def test_end_outside_a_rounded_end_stops_where_its_section_is_full():
    distance = closed_tube(rounded=True)
    skel = axis_skeleton(L + 1.1 * R)
    out, n_pulled, _ = pull_inside(skel, distance)
    end = out.points[np.argmax(out.points[:, 2])]
    # the hemisphere's tip is at L + R; its cross-sections are full (side wall within
    # 30 degrees of the axis) from about half a radius behind it
    assert n_pulled == 1 and L + 0.2 * R <= end[2] <= L + 0.5 * R
    assert np.hypot(*end[:2]) < 0.05 * R


def test_a_branch_shorter_than_the_way_back_is_walked_up_the_distance():
    # an end node alone outside, its branch ending at a junction right behind the face:
    # the walk along the branch would pass the junction, so the old walk decides
    distance = closed_tube(rounded=False)
    skel = axis_skeleton(L + 0.13 * R, spacing=0.3, junction_at=L - 0.05)
    out, n_pulled, n_dropped = pull_inside(skel, distance)
    assert n_pulled == 1 and n_dropped == 0 and (out.degrees >= 3).sum() == 1
    assert (distance(out.points) > -0.02 * R).all()


def test_ends_inside_and_side_nodes_are_untouched():
    distance = closed_tube(rounded=False)
    skel = axis_skeleton(L - 0.2 * R)
    out, n_pulled, n_dropped = pull_inside(skel, distance)
    assert n_pulled == n_dropped == 0 and np.array_equal(out.points, skel.points)


@pytest.mark.slow
def test_given_end_past_a_terraced_end_stays_at_it():
    # a small generated voxel-staircase vessel, its true skeleton given: one end lies
    # 0.12 radii outside its closed, terraced end (found as no cap); before, clean_skeleton
    # pulled it 1.05 radii back (the mesh stopped that short of the end)
    pytest.importorskip("igl")
    from test_staircase_caps import _capped
    from test_vessel_generator import NONE, SMALL
    from data_synthetic import vessel_generator as G
    from vmesh.registry import get_filter

    ves = G.generate_vessel(2, "clean", rates={**NONE, "staircase": 1.0}, end_style="flat", **SMALL)
    ctx = _capped(ves)
    ends = np.flatnonzero(np.bincount(ves.edges.ravel(), minlength=len(ves.xyz)) == 1)
    d = ctx.sdf.distance(ves.xyz[ends]) / ves.radius[ends]
    out = ends[d < -0.05]
    assert len(out) == 1
    get_filter("estimate_radii")(ctx)
    get_filter("clean_skeleton")(ctx)
    sk = ctx.skeleton
    new_ends = sk.points[sk.degrees == 1]
    gap = np.linalg.norm(new_ends - ves.xyz[out], axis=1).min() / ves.radius[out[0]]
    assert gap < 0.8
    assert (ctx.sdf.distance(new_ends) > 0).all()


def test_an_end_on_its_end_face_stays():
    # an end on the end face itself (inside, within the outside tolerance) stays: moved back
    # a quarter radius, it left the slab behind it out of the mesh where the face is a
    # filled open end (seed 0 g0000 given failed coverage so, session 15)
    distance = closed_tube(rounded=False)
    skel = axis_skeleton(L - 0.01 * R)
    for keep in (None, np.zeros(skel.n_nodes, bool)):
        same, n_pulled, n_dropped = pull_inside(skel, distance, keep=keep)
        assert n_pulled == n_dropped == 0 and np.array_equal(same.points, skel.points)


def test_an_end_at_a_cap_outside_it_is_not_moved_back_along_its_branch():
    distance = closed_tube(rounded=False)
    skel = axis_skeleton(L + 0.13 * R)
    keep = skel.degrees == 1
    keep[0] = False  # the end at z = 1 is inside anyway
    out, n_pulled, _ = pull_inside(skel, distance, keep=keep)
    # walked up the signed distance as before (not cut back along the branch)
    assert out.n_nodes == skel.n_nodes and n_pulled == 1
