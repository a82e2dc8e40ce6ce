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
