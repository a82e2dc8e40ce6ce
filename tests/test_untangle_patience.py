"""The light pass's untangling stops growing around a fold no ring opens (issue 17/18).

On a large tree whose two vessels were fused across each other the light pass (``untangle_below = 0``) re-untangled the elements the
untanglers had left inverted (two vessels fused across each other) and grew its region 63
rings, twice (first layer held, then free), re-sweeping all of it each ring: ~700 of the
mesher's 1,818 s wall. With ``untangle_patience`` the region stops growing once that many
rings in a row leave as many elements below the goal and their minimum no higher.
"""

from __future__ import annotations

import numpy as np

import vmesh.geometry.optimize as opt
from vmesh.geometry.optimize import optimise_linear


def _grid(n: int):
    """An n x n x n block of unit hexahedra (tensor corner order)."""
    a = np.arange(n + 1, dtype=float)
    z, y, x = np.meshgrid(a, a, a, indexing="ij")
    points = np.c_[x.ravel(), y.ravel(), z.ravel()]
    i, j, k = np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij")
    base = (i + (n + 1) * (j + (n + 1) * k)).ravel()
    off = np.array([(c & 1) + (n + 1) * (((c >> 1) & 1) + (n + 1) * ((c >> 2) & 1)) for c in range(8)])
    return points, base[:, None] + off[None, :]


def _stuck_fold(n: int = 20):
    """The grid with its middle element mirrored (top face below the bottom one) and its
    eight nodes held: no move of the free nodes can open it."""
    points, cells = _grid(n)
    mid = (n // 2) + n * ((n // 2) + n * (n // 2))
    c = cells[mid]
    z0, z1 = points[c[0], 2], points[c[4], 2]
    points[c[:4], 2], points[c[4:], 2] = z0 + 0.7, z1 - 0.7
    held = np.zeros(len(points), bool)
    held[c] = True
    a = points
    held |= (a == 0).any(axis=1) | (a == n).any(axis=1)  # the block's own boundary stays too
    return points, cells, held, mid


def test_region_stops_growing_around_a_fold_no_ring_opens():
    points, cells, held, mid = _stuck_fold()
    kw = dict(boundary=held, untangle_below=0.0, smooth_below=0.0, max_fraction=1.0)
    X0, grown = optimise_linear(points, cells, **kw)
    X1, bounded = optimise_linear(points, cells, untangle_patience=3, **kw)
    # the mirrored element stays inverted either way, and is the worst
    assert grown["after"]["min"] < 0 and bounded["after"]["min"] == grown["after"]["min"]
    # without patience the region grows ring after ring; with it, 3 rings past the last
    # drop in inverted elements
    assert grown["rings"] >= 8
    assert bounded["rings"] <= 4
    assert bounded["untangled_nodes"] < grown["untangled_nodes"]
    # the nodes the bounded pass did not reach are where they were
    assert np.array_equal(X1[held], points[held])


def test_patience_changes_nothing_where_the_fold_opens():
    """A fold the first rings open: the same points with and without patience."""
    points, cells = _grid(8)
    held = (points == 0).any(axis=1) | (points == 8).any(axis=1)
    node = 4 + 9 * (4 + 9 * 4)  # an inner node pushed through its neighbours
    points[node] += [0.9, 0.8, 0.85]
    kw = dict(boundary=held, untangle_below=0.0, smooth_below=0.0, max_fraction=1.0)
    X0, a = optimise_linear(points, cells, **kw)
    X1, b = optimise_linear(points, cells, untangle_patience=3, **kw)
    assert a["before"]["min"] < 0 and a["after"]["min"] > 0
    assert np.array_equal(X0, X1) and a["rings"] == b["rings"]


def test_patience_keeps_growing_while_the_minimum_rises(monkeypatch):
    """A fold that stays one inverted element for six rings while its minimum rises ring
    by ring, then opens: no ring is a stall (the count is flat, the minimum is not), so the
    growth goes on until it opens instead of stopping after 3 rings."""
    mins = [-0.9, -0.8, -0.7, -0.6, -0.5, -0.4]

    def scripted(X, st, *args, **kw):
        ring = scripted.calls
        scripted.calls += 1
        return np.array([mins[ring], 1.0, 1.0]) if ring < len(mins) else np.full(3, 0.5)

    points, cells = _grid(20)
    held = (points == 0).any(axis=1) | (points == 20).any(axis=1)
    points[4 + 21 * (10 + 21 * 10)] += [0.9, 0.8, 0.85]  # an inner node pushed through its neighbours
    monkeypatch.setattr(opt, "_run_stage", scripted)
    kw = dict(boundary=held, untangle_below=0.0, smooth_below=0.0, max_fraction=1.0, untangle_patience=3)
    scripted.calls = 0
    _, info = optimise_linear(points, cells, **kw)
    assert info["rings"] == len(mins)
    # the count and the minimum both flat: stalled after 3 rings
    mins[:] = [-0.9] * 6
    scripted.calls = 0
    _, info = optimise_linear(points, cells, **kw)
    assert info["rings"] == 3
