"""Junction axes, half-planes and their rotations (steps 1 and 4 of the method)."""

from __future__ import annotations

import numpy as np

from ...errors import MeshingError
from .. import cross_sections as cs
from .options import JUNCTION, _Candidates, _Junction
from ..skeleton.graph import polyline_at
from .prep import split_nonplanar_junctions

# how far separate_junctions may move a junction (and _carry_next_nodes a next node it
# takes along): within MOVE_BOUND node radii of its skeleton point, and MOVE_DEPTH of its
# radius inside the wall, so that it stays in the lumen the skeleton put it in
MOVE_BOUND = 1.5
MOVE_DEPTH = 0.4


class _Junctions:
    """Junction steps of the block builder: axes, separators, centres and half-plane
    rotations. Mixed into :class:`~vmesh.geometry.blocks.builder._Builder`, whose state
    they share."""

    # -- 2. junctions ------------------------------------------------------------
    def junction_problem(self, c: int, d: np.ndarray):
        """The junction axis of node ``c`` with neighbour directions ``d``, or why the scheme cannot take it."""
        opt = self.opt
        u, gap, elev = cs.junction_axis(d, np.radians(opt.junction.max_out_of_plane))
        if elev > np.radians(opt.junction.max_out_of_plane):
            k = int(np.argmax(np.abs(d @ u)))
            return u, (k, f"one of its branches leaves the junction plane by {np.degrees(elev):.0f} degrees (more than max_out_of_plane = {opt.junction.max_out_of_plane:g})")
        if gap < np.radians(opt.junction.min_branch_gap):
            return u, (None, f"two of its branches are only {np.degrees(gap):.0f} degrees apart around the junction axis (less than min_branch_gap = {opt.junction.min_branch_gap:g})")
        return u, None

    def split_if_needed(self):
        """With ``split_nonplanar``: split n-furcations (4+ branches) that are too far from planar
        into chains of 3-junctions. Other problems are reported by :meth:`build_junctions`."""
        if not self.opt.repair.split_nonplanar:
            return
        sk = self.topo.sk
        split = []
        for c in sk.junctions.tolist():
            nb = sk.neighbors(c)
            if len(nb) <= 3:
                continue
            _, problem = self.junction_problem(c, cs.unit(sk.points[nb] - sk.points[c]))
            if problem:
                split.append(c)
        if split:
            self.topo.sk = split_nonplanar_junctions(sk, split, distance=self.sdf)
            self.fixes.append(f"split non-planar junction node(s) {split} into 3-junctions")
            self.warn(f"split non-planar junction node(s) {split} into 3-junctions")
            self.check_skeleton()

    def _branch_direction(self, bi: int, side: int, length: float) -> np.ndarray:
        """Unit direction from a branch end (its current position) to the point ``length``
        further along the branch's nodes (at least its first neighbour)."""
        br = self.topo.branches[bi]
        nodes = br.nodes if side == 0 else br.nodes[::-1]
        P = self.topo.sk.points[nodes]
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
        s = np.array([max(min(length, arc[-1]), arc[1])])
        target, _ = polyline_at(P, arc, s, np.zeros((len(P), 1)))
        return cs.unit(target[0] - self.topo.pos[nodes[0]])

    def build_junctions(self, nodes=None):
        """Junction axes, neighbour order and separators (from the current positions), for
        all junctions or only ``nodes``."""
        sk = self.topo.sk
        if nodes is None:
            self.topo.junctions = {}
        ends = {}
        for bi, br in enumerate(self.topo.branches):
            for side in (0, 1):
                if br.kinds[side] == JUNCTION:
                    c = int(br.nodes[0] if side == 0 else br.nodes[-1])
                    ends.setdefault(c, []).append((bi, side))
        for c, lst in ends.items():
            if nodes is not None and c not in nodes:
                continue
            moved = float(np.linalg.norm(self.topo.pos[c] - sk.points[c]))
            rc = float(sk.radii[c])
            # directions to the first neighbours; further along the branches when those are
            # nearly parallel (a junction node placed before the vessels really part)
            first = None
            for ahead in (0.0, 1.5, 2.0, 3.0, 4.0):
                length = max(moved + 0.5 * rc, ahead * rc) if (moved > 0 or ahead > 0) else 0.0
                d = np.stack([self._branch_direction(bi, side, length) for bi, side in lst])
                u, problem = self.junction_problem(c, d)
                if first is None:
                    first = problem
                if problem is None:
                    if ahead > 0 and c not in self.local.lookahead:
                        self.local.lookahead[c] = ahead
                        self.fixes.append(f"junction node {c}: branch directions taken {ahead:g} radii along its branches ({first[1]} at its first neighbours)")
                    break
            if problem:
                k, why = first
                m = len(lst)
                if k is not None:
                    nb = int(self.topo.branches[lst[k][0]].nodes[1] if lst[k][1] == 0 else self.topo.branches[lst[k][0]].nodes[-2])
                    why = why.replace("one of its branches", f"its branch towards node {nb}")
                hint = (
                    "; set split_nonplanar = true to split it into 3-junctions"
                    if m > 3
                    else "; move the junction node or resample the skeleton so that its branches spread around it"
                )
                raise MeshingError(f"junction at skeleton node {c} ({m} branches) is beyond the junction scheme: {why}{hint}")
            ang, p, q = cs.order_around(u, d)
            order, sep, gap = cs.separator_angles(ang)
            self.topo.junctions[c] = _Junction(
                node=c, center=self._junction_centre(c, u, p, q, sep), radius=float(sk.radii[c]), u=u, p=p, q=q,
                neighbors=np.array([int(self.topo.branches[bi].nodes[1] if side == 0 else self.topo.branches[bi].nodes[-2]) for bi, side in lst])[order],
                dirs=d[order], separator=sep, gap=gap, psi=np.zeros(len(lst)), ends=[lst[i] for i in order],
            )

    def _junction_centre(self, c: int, u, p, q, sep) -> np.ndarray:
        """Point of the junction's common line (the half-sections' spine).

        As vascularmd places a bifurcation's centre (Decroocq et al. 2023), the line goes
        through the mean of the wall points straight out along the separators (the apex
        of each crotch and the outer walls between branches), centred between the wall
        above and below along ``u``. A node far upstream of the apex would otherwise cast
        the crotch half-section as a long sliver that reaches along the daughters and
        folds their first boundary-layer blocks. ``junction_centre`` blends from the node
        (0) to that point (1); it stays at least half the node's radius inside."""
        o = self.topo.pos[c].copy()
        w = float(self.opt.junction.junction_centre)
        if w <= 0 or c in self.local.at_node:
            return o
        rc = float(self.topo.sk.radii[c])
        sd = np.cos(sep)[:, None] * p + np.sin(sep)[:, None] * q
        R = self.cast(np.repeat(o[None], len(sd), 0), sd, np.full(len(sd), rc))
        if not np.all(np.isfinite(R)):
            return o
        x = o + w * np.mean(R[:, None] * sd, axis=0)
        ud = self.cast(np.repeat(x[None], 2, 0), np.stack([u, -u]), np.full(2, rc))
        if np.all(np.isfinite(ud)):
            x = x + 0.5 * (ud[0] - ud[1]) * u
        if float(np.asarray(self.sdf(x[None]))[0]) < 0.5 * rc:
            return o
        return x

    def _slack(self, bi: int) -> float:
        """Room left on a branch between two junctions once both half-sections are in."""
        br = self.topo.branches[bi]
        L = float(np.linalg.norm(self.topo.pos[br.nodes[-1]] - self.topo.pos[br.nodes[0]])) if len(br.nodes) == 2 else br.arc[-1]
        return L - self._junction_reach(bi, 0) - self._junction_reach(bi, 1)

    def separate_junctions(self, bi: int) -> bool:
        """Move one end junction of a branch between two junctions away from the other.

        Each end is tried (half a branch radius along the branch, into the wedge of the
        junction's other branches, staying well inside and within 1.5 radii of its node);
        the move that leaves the branch most room is kept. With ``carry_next_nodes``, a
        move that brings another branch's next node within the junction's half-sections
        takes that node along (:meth:`_carry_next_nodes`)."""
        sk = self.topo.sk
        br = self.topo.branches[bi]
        if br.kinds != [JUNCTION, JUNCTION] or br.nodes[0] == br.nodes[-1]:
            return False
        rb = float(np.median(sk.radii[br.nodes]))
        base = self._slack(bi)
        best = None
        for side in (0, 1):
            c = int(br.nodes[0] if side == 0 else br.nodes[-1])
            other = int(br.nodes[-1] if side == 0 else br.nodes[0])
            w = cs.unit(self.topo.pos[c] - self.topo.pos[other])
            new = self.topo.pos[c] + 0.5 * rb * w
            if np.linalg.norm(new - sk.points[c]) > MOVE_BOUND * sk.radii[c]:
                continue
            if float(np.asarray(self.sdf(new[None]))[0]) < MOVE_DEPTH * sk.radii[c]:
                continue
            old_pos, old_j = self.topo.pos.copy(), self.topo.junctions[c]
            carried = []
            try:
                carried = self._moved_junction(c, bi, new)
                gain = self._slack(bi) - base
            except MeshingError:
                gain = -np.inf
            self.topo.pos[:] = old_pos
            self.topo.junctions[c] = old_j
            self._rebuild_branches()
            if best is None or gain > best[0]:
                best = (gain, c, new, carried)
        if best is None or best[0] <= 1e-9 * rb:
            return False
        _, c, new, _ = best
        carried = self._moved_junction(c, bi, new)
        moved = float(np.linalg.norm(new - sk.points[c]))
        self.fixes.append(f"moved junction node {c} by {moved:.3g} along its branch to node {int(br.nodes[0] if c == br.nodes[-1] else br.nodes[-1])}"
                          + (f", taking along its next node(s) {carried}" if carried else ""))
        return True

    def _moved_junction(self, c: int, bi: int, new: np.ndarray) -> list:
        """Put junction ``c`` at ``new`` (away along branch ``bi``) and rebuild it; with
        ``carry_next_nodes`` also :meth:`_carry_next_nodes`. Returns the nodes carried."""
        if not self.opt.repair.carry_next_nodes:
            self.topo.pos[c] = new
            self._rebuild_junction(c)
            return []
        first = self._first_lengths(c, bi)
        delta = new - self.topo.pos[c]
        self.topo.pos[c] = new
        self._rebuild_junction(c)
        return self._carry_next_nodes(c, bi, delta, first)

    def _first_lengths(self, c: int, bi: int) -> dict:
        """Length of the first segment of each branch of junction ``c`` but ``bi``, by its next node."""
        out = {}
        for bj, side in self.topo.junctions[c].ends:
            if bj == bi:
                continue
            nodes = self.topo.branches[bj].nodes
            nb = int(nodes[1] if side == 0 else nodes[-2])
            out[nb] = float(np.linalg.norm(self.topo.pos[nb] - self.topo.pos[c]))
        return out

    def _carry_next_nodes(self, c: int, bi: int, delta: np.ndarray, first: dict) -> list:
        """Move by ``delta`` (the junction's own move) each plain next node of junction
        ``c``'s other branches that its move brought closer and now within the reach of the
        junction's half-sections along that branch.

        Moving a junction away from a close neighbour (:meth:`separate_junctions`) can
        walk it into another of its branches: that branch's first segment becomes a stub
        shorter than the half-sections' reach, its first cross-section stands inside the
        junction and the boundary-layer blocks between them collapse onto the wall
        (docs/junctions.md, two overlapping junctions). Carried along, the node keeps the
        first segment's length and direction; the branch's second segment gives up the room
        instead. A node is
        carried only where it stays ``MOVE_DEPTH`` of its radius inside the wall and
        within ``MOVE_BOUND`` radii of its skeleton point (the junction's own bounds)."""
        sk = self.topo.sk
        deg = sk.degrees
        carried = []
        for bj, side in self.topo.junctions[c].ends:
            if bj == bi:
                continue
            nodes = self.topo.branches[bj].nodes
            nb = int(nodes[1] if side == 0 else nodes[-2])
            L = float(np.linalg.norm(self.topo.pos[nb] - self.topo.pos[c]))
            if deg[nb] != 2 or nb not in first or L >= first[nb] or L >= self._junction_reach(bj, side):
                continue
            to = self.topo.pos[nb] + delta
            if np.linalg.norm(to - sk.points[nb]) > MOVE_BOUND * sk.radii[nb]:
                continue
            if float(np.asarray(self.sdf(to[None]))[0]) < MOVE_DEPTH * sk.radii[nb]:
                continue
            self.topo.pos[nb] = to
            carried.append(nb)
        if carried:
            self._rebuild_junction(c)
        return carried

    def _rebuild_branches(self):
        self.make_branches()
        self.classify_ends()

    def _rebuild_junction(self, c: int):
        self._rebuild_branches()
        self.build_junctions({c})
        self.choose_rotations({c})


    # -- 4. junction half-planes --------------------------------------------------
    def _neighbour_room(self, j: _Junction) -> np.ndarray:
        """How far (along each ordered neighbour's branch) sections may be pushed."""
        room = np.empty(len(j.neighbors))
        for h, (bi, side) in enumerate(j.ends):
            br = self.topo.branches[bi]
            L = br.arc[-1]
            other = br.kinds[1 - side]
            room[h] = (0.45 if other == JUNCTION else 0.8) * L if len(br.nodes) > 2 else 0.85 * L
        return room

    def _half_rays(self, j: _Junction, sdirs: np.ndarray, seps=None) -> np.ndarray:
        """Ray lengths (k, nr) of half-sections with in-plane directions ``sdirs`` (k, 3) at
        separators ``seps`` (k,; default: separator ``i`` for ``sdirs[i]``), leaning as
        :meth:`_leaned` says; angles in (π, 2π) mirror the
        upper half, 0 and π are the spine."""
        t = self.template
        ang = t.ray_angles
        up = (ang > 1e-9) & (ang < np.pi - 1e-9)
        k = len(sdirs)
        s = self._leaned(j, sdirs, seps, np.broadcast_to(ang[up], (k, int(up.sum()))))
        dirs = np.cos(ang[up])[None, :, None] * j.u + np.sin(ang[up])[None, :, None] * s
        o = np.repeat(j.center[None, :], dirs.shape[0] * dirs.shape[1], axis=0)
        R_up = self.cast(o, dirs.reshape(-1, 3), np.full(len(o), j.radius)).reshape(k, -1)
        R = np.empty((k, len(ang)))
        R[:, up] = R_up
        idx_up = np.flatnonzero(up)
        lower = np.flatnonzero(ang > np.pi + 1e-9)
        mirror_of = cs.ray_index(t, cs._TWO_PI - ang[lower])
        pos = {int(v): n for n, v in enumerate(idx_up)}
        R[:, lower] = R_up[:, [pos[int(v)] for v in mirror_of]]
        spine = self.spine_rays(j)
        R[:, cs.ray_index(t, 0.0)] = spine[0]
        R[:, cs.ray_index(t, np.pi)] = spine[1]
        return R

    def leans(self, j: _Junction) -> bool:
        """Whether the half-sections of ``j`` lean (:meth:`_leaned`): an n-furcation whose
        branches leave its plane unalike, with ``junction_lean`` on and not in ``local.planar``."""
        return (self.opt.junction.junction_lean > 0 and len(j.neighbors) >= 4 and j.node not in self.local.planar
                and float(np.ptp(j.dirs @ j.u)) > 1e-6)

    def _leaned(self, j: _Junction, sdirs: np.ndarray, seps: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """In-plane directions (k, n, 3) of half-sections ``sdirs`` (k, 3) at separators
        ``seps`` at the polar angles ``theta`` (k, n) from ``u``, turned about ``u``.

        A half-plane through ``u`` bisects two branches only where they leave the junction
        plane alike (every 3-junction: ``u`` is the normal of its branches' tips' plane).
        Where one of the two dips towards a pole (a trifurcation's branch out of the plane),
        the half-plane's part towards that pole runs into that branch, and its boundary
        layer folds. The half-section therefore leans: at polar angle θ it turns about ``u``
        by δ(θ), towards the angle bisector of the two branches (``v · (d_a - d_b) = 0``,
        ``sin δ ≈ κ cot θ``), smoothly bounded by half the room left to either branch
        (``δ = δ_max tanh(κ cot θ / δ_max)``). At the equator (θ = π/2) and on the spine it
        is the half-plane as before; ``junction_lean`` scales it. The junctions in
        ``local.planar`` keep their half-planes (:meth:`choose_planes`)."""
        seps = np.arange(len(sdirs)) if seps is None else np.asarray(seps)
        if not self.leans(j):
            return np.broadcast_to(sdirs[:, None, :], theta.shape + (3,))
        w = float(self.opt.junction.junction_lean)
        m = len(j.neighbors)
        a, b = j.dirs[seps], j.dirs[(seps + 1) % m]
        t0 = np.cross(j.u, sdirs)
        tw = np.sum(t0 * (a - b), axis=1)
        kappa = np.where(np.abs(tw) > 1e-9, -((a - b) @ j.u) / np.where(np.abs(tw) > 1e-9, tw, 1.0), 0.0)

        def az(d):
            return np.arctan2(d @ j.q, d @ j.p)

        room = np.minimum(np.mod(az(sdirs) - az(a), cs._TWO_PI), np.mod(az(b) - az(sdirs), cs._TWO_PI))
        dmax = np.maximum(0.5 * w * room, 1e-9)[:, None]
        cot = np.cos(theta) / np.maximum(np.sin(theta), 1e-6)
        delta = dmax * np.tanh(kappa[:, None] * cot / dmax)
        return np.cos(delta)[..., None] * sdirs[:, None, :] + np.sin(delta)[..., None] * t0[:, None, :]

    def spine_rays(self, j: _Junction) -> np.ndarray:
        o = np.repeat(j.center[None, :], 2, axis=0)
        return self.cast(o, np.stack([j.u, -j.u]), np.full(2, j.radius))

    def _half_vertices(self, j: _Junction, sdirs: np.ndarray, R: np.ndarray, core=None, layer=None, seps=None) -> np.ndarray:
        """Vertices (k, nv, 3) of half-sections: the template in each half-plane, each vertex
        then turned about ``u`` as its polar angle's ray leans (:meth:`_leaned`), so that the
        wall vertices land where the leaning rays hit the wall."""
        k = len(sdirs)
        e1 = np.repeat(j.u[None, :], k, axis=0)
        c = np.repeat(j.center[None, :], k, axis=0)
        core = self.opt.section.core_size if core is None else core
        layer = self.opt.section.layer_thickness if layer is None else layer
        V = cs.section_vertices(self.template, c, e1, sdirs, R, core, layer)
        if not self.leans(j):
            return V
        rel = V - j.center
        h_u = rel @ j.u
        h_s = np.einsum("knj,kj->kn", rel, sdirs)
        s = self._leaned(j, sdirs, seps, np.arctan2(np.abs(h_s), h_u))
        return j.center + h_u[..., None] * j.u + h_s[..., None] * s

    def choose_rotations(self, nodes=None):
        opt = self.opt
        ncand = max(1, int(opt.junction.rotation_candidates))
        for c, j in self.topo.junctions.items():
            if nodes is not None and c not in nodes:
                continue
            m = len(j.neighbors)
            spine = self.spine_rays(j)
            if np.any(~np.isfinite(spine)):
                raise MeshingError(f"junction at skeleton node {c}: no wall found along its reference line (is the node inside the vessel?)")
            # candidate offsets per separator, symmetric about the bisector
            frac = np.linspace(-1.0, 1.0, ncand) if ncand > 1 else np.zeros(1)
            psi = (opt.junction.rotation_range * 0.5 * j.gap)[:, None] * frac[None, :]  # (m, ncand)
            ang = j.separator[:, None] + psi
            sdirs = np.cos(ang)[..., None] * j.p + np.sin(ang)[..., None] * j.q  # (m, ncand, 3)
            seps = np.repeat(np.arange(m), ncand)
            R = self._half_rays(j, sdirs.reshape(-1, 3), seps)
            if np.any(~np.isfinite(R)):
                bad = ~np.all(np.isfinite(R), axis=1).reshape(m, ncand)
                if bad.all(axis=1).any():
                    raise MeshingError(f"junction at skeleton node {c}: a half cross-section finds no wall within reach")
            V = self._half_vertices(j, sdirs.reshape(-1, 3), np.nan_to_num(R, nan=1e6), seps=seps).reshape(m, ncand, -1, 3)
            upper = self.template.upper
            rel = V[:, :, upper] - j.center
            mean_dist = np.linalg.norm(rel, axis=3).mean(axis=2)  # (m, ncand)
            # reach of each half-section along its two neighbours' directions
            dirs = j.dirs
            room = self._neighbour_room(j)
            rad = self.topo.sk.radii[j.neighbors]
            # reach along the branches from the node (the half-sections' line may be off it)
            reach_a = (rel @ dirs.T) + ((j.center - self.topo.pos[c]) @ dirs.T)  # (m, ncand, nv_up, m)
            over = np.zeros((m, ncand))
            for h in range(m):
                for nbh in (h, (h + 1) % m):
                    r = reach_a[h, :, :, nbh].max(axis=1)
                    over[h] += np.maximum(0.0, r + opt.junction.junction_margin * rad[nbh] - room[nbh]) / rad[nbh]
            cost = mean_dist / j.radius + 10.0 * over + 0.05 * frac[None, :] ** 2
            cost[~np.isfinite(R).all(axis=1).reshape(m, ncand)] = np.inf
            if opt.junction.junction_rotation == "bisector":
                pick = np.full(m, ncand // 2)
            else:
                pick = np.argmin(cost, axis=1)
            j.cand = _Candidates(psi=psi, cost=cost, reach=reach_a.max(axis=2), pick=pick)  # reach: (m, ncand, m)
            j.psi = psi[np.arange(m), pick]

    def _junction_end(self, bi: int, side: int):
        """The junction at one end of a branch, and that end's place ``h`` among its
        ordered neighbours: the half-planes next to the end are separators ``h - 1`` and ``h``."""
        br = self.topo.branches[bi]
        j = self.topo.junctions[int(br.nodes[0] if side == 0 else br.nodes[-1])]
        h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
        return j, h, ((h - 1) % len(j.neighbors), h)

    def _junction_reach(self, bi: int, side: int) -> float:
        """How far the half-sections of the junction at a branch's end reach along it."""
        j, h, seps = self._junction_end(bi, side)
        return float(max(j.cand.reach[sp, j.cand.pick[sp], h] for sp in seps))
