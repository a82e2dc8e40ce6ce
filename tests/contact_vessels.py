"""Small generated vessels whose branches pass each other in contact (issue 18): surfaces
made as the vessel generator makes them (smooth union of tubes, marching cubes, open ends),
their true skeleton written beside them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_synthetic.vessel_generator import Vessel, finish_surface, tag_ends, write_vessel
from data_synthetic.vessels import surface as S
from data_synthetic.vessels import tree as T


def passing_vessels(folder, gap: float, cross: float = 0.0, units: str = "mm") -> dict:
    """A parent tube along x (radius 1.2, from x = -8 to 14) with a side branch ``S`` up +y
    from x = 6 (radius 1) and a branch ``K`` from the origin (radius 0.7) that passes ``S``
    with its axis ``gap`` from S's axis (the walls touch at 1.7, fuse into a neck below),
    leaning ``cross`` radians out of the xy-plane (0: K runs alongside S's side, kissing;
    more: it crosses S). Writes the vessel's files into ``folder``; returns its manifest."""
    tree = T.Tree()
    p, r = T.straight(np.array([-8.0, 0, 0]), np.array([14.0, 0, 0]), 1.2, 1.2)
    tree.branches.append(T.Branch(p, r))
    at_s, at_k = int(np.argmin(np.abs(p[:, 0] - 6.0))), int(np.argmin(np.abs(p[:, 0])))
    p_s, r_s = T.straight(p[at_s], p[at_s] + [0.0, 12.0, 0.0], 1.0, 1.0)
    tree.branches.append(T.Branch(p_s, r_s, 0, at_s))
    # K from the origin towards the point at height 8 on S's axis, shifted by ``gap`` off it
    passing = np.array([6.0 - gap * np.sin(cross), 8.0, gap * np.cos(cross)])
    d = passing / np.linalg.norm(passing)
    p_k, r_k = T.straight(p[at_k], p[at_k] + (np.linalg.norm(passing) + 3.0) * d, 0.7, 0.7)
    tree.branches.append(T.Branch(p_k, r_k, 0, at_k, kind="kissing"))
    xyz, radius, tags, edges, caps, V, Tri = _open_vessel(tree, 0.7 / 2.6)
    manifest = {"name": f"passing_{gap:g}_{cross:g}", "units": units, "surface_format": "ply"}
    return write_vessel(Vessel(V, Tri, xyz, radius, tags, edges, manifest), Path(folder))



def acute_fork(folder, angle: float, parallel: float = 0.0, apart: float = 1.8, radius: float = 1.4, length: float = 14.0,
               units: str = "mm") -> dict:
    """A parent tube along x (``radius``, 14 long) forking at the origin into two daughters
    (0.95 ``radius``) ``angle`` degrees apart; with ``parallel`` > 0 they turn alongside
    each other once their axes are ``apart`` apart (their walls fused when that is below
    1.9 ``radius``), run so ``parallel`` long, then part 40 degrees apart for ``length``.
    Writes the vessel's files into ``folder``; returns its manifest."""
    tree = T.Tree()
    p, r = T.straight(np.array([-length, 0, 0]), np.zeros(3), radius, radius)
    tree.branches.append(T.Branch(p, r))
    rd = 0.95 * radius
    for sign in (1.0, -1.0):
        a = np.radians(sign * angle / 2)
        d = np.array([np.cos(a), np.sin(a), 0.0])
        if parallel > 0:
            turn = d * (0.5 * apart / abs(np.sin(a)))
            ahead = turn + [parallel, 0.0, 0.0]
            b = np.radians(sign * 20.0)
            legs = [(np.zeros(3), turn), (turn, ahead), (ahead, ahead + length * np.array([np.cos(b), np.sin(b), 0.0]))]
        else:
            legs = [(np.zeros(3), length * d)]
        q = np.concatenate([T.straight(u, v, rd, rd)[0][(0 if k == 0 else 1):] for k, (u, v) in enumerate(legs)])
        tree.branches.append(T.Branch(q, np.full(len(q), rd), 0, len(p) - 1))
    xyz, rad, tags, edges, caps, V, Tri = _open_vessel(tree, rd / 2.6)
    manifest = {"name": f"acute_fork_{angle:g}_{parallel:g}", "units": units, "surface_format": "ply"}
    return write_vessel(Vessel(V, Tri, xyz, rad, tags, edges, manifest), Path(folder))


def end_cut_through_neighbour(folder, offset: float = 1.5, units: str = "mm") -> dict:
    """A tube along x (radius 1.2) from x = -10 that ends open at x = 0, and a thin branch
    (radius 0.45) leaving it at x = -8 that runs nearly alongside, its axis ``offset`` from
    the tube's axis at x = 0 (the walls touching there), and ends open at x = 3. The tube's
    end is cut raggedly as the generator cuts open ends, through the thin branch's wall too
    (docs/robustness.md h22/fold: s0 g0015): one boundary loop, the tube's rim with a window
    of the thin branch's wall spliced in. Writes the vessel's files; returns its manifest."""
    tree = T.Tree()
    p, r = T.straight(np.array([-10.0, 0, 0]), np.zeros(3), 1.2, 1.2)
    tree.branches.append(T.Branch(p, r))
    at = int(np.argmin(np.abs(p[:, 0] + 8.0)))
    tip = np.array([3.0, offset * 11.0 / 8.0, 0.0])
    p_k, r_k = T.straight(p[at], tip, 0.45, 0.45)
    tree.branches.append(T.Branch(p_k, r_k, 0, at, kind="kissing"))
    xyz, radius, tags, edges, caps, V, Tri = _open_vessel(tree, 0.45 / 2.6)
    tube_end = [c for c in caps if abs(c[0][0]) < 1e-9 and np.linalg.norm(c[0][1:]) < 1e-9]
    V, Tri = S.ragged_cut(V, Tri, tube_end, np.random.default_rng(0))
    manifest = {"name": f"end_cut_through_neighbour_{offset:g}", "units": units, "surface_format": "ply"}
    return write_vessel(Vessel(V, Tri, xyz, radius, tags, edges, manifest), Path(folder))


def end_cut_at_parent_wall(folder, angle: float = 45.0, length: float = 1.0, units: str = "mm") -> dict:
    """A tube along x (radius 1.2, x = -8 to 8) with a short side branch (radius 0.45) leaving
    its axis at the origin ``angle`` degrees from +x and ending open ``length`` of its radii
    past the tube's wall (a stub). The stub's end is cut raggedly as the generator cuts open
    ends, through the tube's wall on the acute side too (docs/robustness.md h23/windows: s0
    g0009, g0007): one boundary loop whose rim runs over the wall of the vessel the stub
    grows out of, not of one passing it. Writes the vessel's files; returns its manifest."""
    tree = T.Tree()
    p, r = T.straight(np.array([-8.0, 0, 0]), np.array([8.0, 0, 0]), 1.2, 1.2)
    tree.branches.append(T.Branch(p, r))
    at = int(np.argmin(np.abs(p[:, 0])))
    d = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
    tip = p[at] + (1.2 / np.sin(np.radians(angle)) + length * 0.45) * d
    tree.branches.append(T.Branch(*T.straight(p[at], tip, 0.45, 0.45), 0, at, kind="stub"))
    xyz, radius, tags, edges, caps, V, Tri = _open_vessel(tree, 0.45 / 2.6)
    stub_end = [c for c in caps if np.linalg.norm(c[0] - tip) < 1e-9]
    V, Tri = S.ragged_cut(V, Tri, stub_end, np.random.default_rng(0))
    manifest = {"name": f"end_cut_at_parent_wall_{angle:g}_{length:g}", "units": units, "surface_format": "ply"}
    return write_vessel(Vessel(V, Tri, xyz, radius, tags, edges, manifest), Path(folder))


def _open_vessel(tree, spacing: float):
    """The tree's skeleton (points, radii, tags with its ends tagged, edges), its end caps
    and its open surface contoured at grid ``spacing``."""
    xyz, radius, tags, edges = T.skeleton_of(tree)
    caps = [(e, n, rr) for _, e, n, rr in S.end_caps(tree)]
    tag_ends(tree, xyz, tags, caps)
    F, grid = S.implicit_field(tree, "open", spacing)
    V, Tri = finish_surface(*S.contour(F, grid, False, smooth_iters=0), caps, "open", target_faces=(10_000, 10**9))
    return xyz, radius, tags, edges, caps, V, Tri
