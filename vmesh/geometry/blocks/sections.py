"""Branches, section positions, frames and ray casts (steps 2 and 3 of the method)."""

from __future__ import annotations

import numpy as np

from ...blocks import FACE_WALL
from ...errors import MeshingError
from .. import cross_sections as cs
from .checks import _Failure
from .options import CLOSED, CYCLE, JUNCTION, OPEN, _Branch
from ..skeleton.graph import polyline_at
from ..skeleton.pairs import PAIR_REACH
from .ended import ended_at_touched_caps
from .prep import Territory, endpoint_caps, redistribute_sections
from ..rays import RAY_REACH, clip_to_territory, cut_at_necks


#: How far (× radius) inside an open end's section its rays start (a flat cap gives the
#: signed distance no sign on its plane).
OPEN_END_SHIFT = 0.05

#: Room (× branch radius) kept for the sections between a junction's half-sections and a
#: closed end whose dome retreat gives way to them (:meth:`_Sections._apply_clearance`).
DOME_YIELD_ROOM = 0.25

#: The most a junction's half-sections are taken to reach along a short branch between two
#: junctions, in the branch's radii (:meth:`_Sections._bounded_reach`).
REACH_RADII = PAIR_REACH  # one value with the skeleton cleaning's pair rule


#: Clean samples in a row (0.25 branch radii apart: one branch radius) that end a
#: junction's crowded stretch along a branch (:meth:`_Sections._clearance`).
CLEAR_RUN = 4


def _first_run(ok: np.ndarray, n: int):
    """Index where the first run of ``n`` True values in a row starts, or None."""
    count = 0
    for i, v in enumerate(ok.tolist()):
        count = count + 1 if v else 0
        if count == n:
            return i - n + 1
    return None


class _Sections:
    """Section steps of the block builder: branches, section positions, frames and ray
    casts. Mixed into :class:`~vmesh.geometry.blocks.builder._Builder`, whose state they
    share."""

    # -- 3. branches -------------------------------------------------------------
    def make_branches(self):
        """Branches along the skeleton's paths (``topo.paths``) at the current node
        positions; rebuilt branches keep their margins and straightening."""
        sk = self.topo.sk
        paths, eids = self.topo.paths
        deg = sk.degrees
        old = self.topo.branches or None
        self.topo.branches = []
        pos, E = self.topo.pos, sk.edges
        # every segment's length at once: a fix that tries junction moves rebuilds the
        # branches of the whole tree per try (the same lengths as per branch, bit for bit)
        length = np.linalg.norm(pos[E[:, 1]] - pos[E[:, 0]], axis=1)
        for n, (nodes, edges) in enumerate(zip(paths, eids)):
            nodes = np.asarray(nodes)
            edges = np.asarray(edges)
            if nodes[0] == nodes[-1] and deg[nodes[0]] == 2:
                kinds = [CYCLE, CYCLE]
            else:
                kinds = [JUNCTION if deg[nodes[0]] >= 3 else "end", JUNCTION if deg[nodes[-1]] >= 3 else "end"]
                if kinds[0] != JUNCTION and kinds[1] == JUNCTION:
                    nodes, edges, kinds = nodes[::-1].copy(), edges[::-1].copy(), kinds[::-1]
            arc = np.r_[0.0, np.cumsum(length[edges])]
            br = _Branch(nodes, edges, kinds, [0, 0], arc, arc.copy(), straighten=np.zeros(len(nodes)))
            if old is not None:
                br.margin = old[n].margin
                br.straighten = old[n].straighten
            self.topo.branches.append(br)


    def classify_ends(self):
        sk = self.topo.sk
        ends = sk.endpoints
        self.ends.cap_of = endpoint_caps(sk.points, sk.radii, ends, self.ends.caps, self.opt.ends.cap_distance)
        names = {FACE_WALL: "wall"}
        if not self.ends.caps:
            # every endpoint is an open end, named by decreasing radius
            order = ends[np.argsort(-sk.radii[ends], kind="stable")]
            self.ends.end_id = {int(e): k + 1 for k, e in enumerate(order.tolist())}
            for k, e in enumerate(order.tolist()):
                names[k + 1] = "inlet" if k == 0 else f"outlet_{k}"
        else:
            self.ends.end_id = {e: cap.id for e, cap in self.ends.cap_of.items()}
            for cap in self.ends.cap_of.values():
                names[int(cap.id)] = cap.name
            unused = [c.name for c in self.ends.caps if all(c is not v for v in self.ends.cap_of.values())]
            if unused and not self.ends.warned_caps:
                self.warn(f"no skeleton endpoint near cap(s) {', '.join(unused)}: those open ends are not meshed")
                self.ends.warned_caps = True
        self.ends.boundary_names = names
        for br in self.topo.branches:
            for side in (0, 1):
                if br.kinds[side] in ("end", OPEN, CLOSED):
                    e = int(br.nodes[0] if side == 0 else br.nodes[-1])
                    if e in self.ends.end_id:
                        br.kinds[side], br.caps[side] = OPEN, self.ends.end_id[e]
                    else:
                        br.kinds[side] = CLOSED


    def _layer_and_core(self, key):
        """Boundary-layer thickness and core size of a section (after local fixes)."""
        layer = min(0.5, self.opt.section.layer_thickness * self.local.layer_scale.get(key, 1.0))
        core = self.opt.section.core_size * self.local.core_scale.get(key, 1.0)
        # keep the core corner inside the ring with some room
        core = min(core, 0.8 * (1.0 - layer) / np.sqrt(2.0))
        return layer, core


    # -- 5. sections ----------------------------------------------------------------
    def _node_normals(self, br: _Branch) -> np.ndarray:
        """Section normal at each node of a branch (pointing along the branch)."""
        sk = self.topo.sk
        P = self.topo.pos[br.nodes]
        K = len(P) - 1
        seg = cs.unit(np.diff(P, axis=0))
        n = np.empty((K + 1, 3))
        n[0], n[K] = seg[0], seg[-1]
        if K >= 2:
            n[1:K] = cs.bisector_normals(P[:-2], P[1:-1], P[2:], sk.radii[br.nodes[1:-1]], self.opt.section.plane_bias)
        if br.kinds[0] == CYCLE:
            n[0] = n[K] = cs.bisector_normals(P[-2:-1], P[:1], P[1:2], sk.radii[br.nodes[:1]], self.opt.section.plane_bias)[0]
        for side, k in ((0, 0), (1, K)):
            if br.kinds[side] == OPEN and br.caps[side] and self.ends.caps:
                cap = self.ends.cap_of[int(br.nodes[k])]
                out = cs.unit(np.asarray(cap.normal, float))
                n[k] = -out if side == 0 else out
        return n


    def _clearance(self):
        """Arc length from each junction along each of its branches where sections are clear."""
        opt, sk, t = self.opt, self.topo.sk, self.template
        jobs = []
        for c, j in self.topo.junctions.items():
            for h, (bi, side) in enumerate(j.ends):
                br = self.topo.branches[bi]
                rb = float(np.median(sk.radii[br.nodes]))
                L = br.arc[-1]
                limit = min((0.45 if br.kinds[1 - side] == JUNCTION else 0.8) * L, 3.0 * j.radius + 2.0 * rb)
                s = 0.25 * rb * np.arange(1, int(limit / (0.25 * rb)) + 1)
                s = s[s < limit]
                if len(s) == 0:
                    continue
                jobs.append((c, h, bi, side, s))
        if not jobs:
            return {}
        centers, normals, radii, owner = [], [], [], []
        for n_job, (c, h, bi, side, s) in enumerate(jobs):
            br = self.topo.branches[bi]
            arc = br.arc if side == 0 else br.arc[-1] - br.arc[::-1]
            nodes = br.nodes if side == 0 else br.nodes[::-1]
            P = self.topo.pos[nodes]
            N = self._node_normals(br)
            N = N if side == 0 else -N[::-1]
            pos, nrm = polyline_at(P, arc, s, N)
            _, rad = polyline_at(P, arc, s, sk.radii[nodes])
            centers.append(pos)
            normals.append(cs.unit(nrm))
            radii.append(rad)
            owner.append(np.full(len(s), n_job))
        centers, normals, radii, owner = map(np.concatenate, (centers, normals, radii, owner))
        e1 = cs.any_perpendicular(normals)
        e2 = np.cross(normals, e1)
        ang = t.loop_angle
        dirs = cs.ray_directions(e1, e2, ang)
        R = self.cast(np.repeat(centers, len(ang), axis=0), dirs.reshape(-1, 3), np.repeat(radii, len(ang)), reach=4.0 * opt.junction.clear_ray_factor)
        R = R.reshape(len(centers), len(ang))
        clean = np.all(np.isfinite(R) & (R <= opt.junction.clear_ray_factor * radii[:, None]), axis=1)
        out = {}
        for n_job, (c, h, bi, side, s) in enumerate(jobs):
            ok = clean[owner == n_job]
            first = _clear_from(ok, s, float(np.median(sk.radii[self.topo.branches[bi].nodes])))
            if opt.last.clear_own_stretch and first > 0:
                # build_blocks' last try: CLEAR_RUN clean candidates in a row end the
                # junction's crowded stretch even when shorter than a branch radius
                # (g0016 extracted: a bulge 2.5-4.7 along a branch of radius 0.67)
                run = _first_run(ok, CLEAR_RUN)
                if run is not None:
                    first = min(first, run)
            out[(bi, side)] = 0.0 if first == 0 else (s[first] if first < len(s) else s[-1])
        return out


    def place_sections(self):
        """Section positions along each branch: clear of junctions, otherwise at the nodes."""
        clear = self._clearance()
        self.placed.clear = clear
        for br in self.topo.branches:
            br.s = br.arc.copy()
        self.placed.retreat = self._dome_retreat()
        self._apply_clearance()


    def _dome_retreat(self) -> dict:
        """How far each closed end's section moves back from its endpoint along the branch.

        The dome beyond a closed end's section is closed by a cap of blocks
        (:meth:`_dome_cap`) that carries the boundary layer round it; the cap needs a dome
        about as high as the section is wide, or its blocks are flattened against the
        section. Endpoints often lie closer to the dome than that (a skeleton ends inside
        the sac, where the inscribed sphere touches the dome): the section goes back to the
        first position (in steps of a tenth of the endpoint's radius, up to
        ``dome_max_retreat`` radii and half the branch) where the wall ahead along the axis
        is at least ``dome_depth`` times the mean distance to the wall in the section, or
        where that ratio is highest.

        Returns
        -------
        dict ``{(branch, side): arc length}``.
        """
        opt, sk, t = self.opt, self.topo.sk, self.template
        jobs = []
        for bi, br in enumerate(self.topo.branches):
            for side in (0, 1):
                if br.kinds[side] != CLOSED:
                    continue
                end = int(br.nodes[-1] if side == 1 else br.nodes[0])
                r_end = float(sk.radii[end])
                limit = min(opt.ends.dome_max_retreat * r_end, 0.5 * br.arc[-1])
                back = np.arange(0.0, limit + 1e-12, 0.1 * r_end)
                jobs.append((bi, side, back))
        if not jobs:
            return {}
        centers, normals, radii, owner = [], [], [], []
        for n_job, (bi, side, back) in enumerate(jobs):
            br = self.topo.branches[bi]
            N = self._node_normals(br)
            s = back if side == 0 else br.arc[-1] - back
            pos, nrm = polyline_at(self.topo.pos[br.nodes], br.arc, s, N)
            _, rad = polyline_at(self.topo.pos[br.nodes], br.arc, s, sk.radii[br.nodes])
            centers.append(pos)
            normals.append(cs.unit(nrm) * (1.0 if side == 1 else -1.0))  # outward
            radii.append(rad)
            owner.append(np.full(len(s), n_job))
        centers, normals, radii, owner = map(np.concatenate, (centers, normals, radii, owner))
        e1 = cs.any_perpendicular(normals)
        e2 = np.cross(normals, e1)
        dirs = np.concatenate([cs.ray_directions(e1, e2, t.loop_angle), normals[:, None, :]], axis=1)
        nr = dirs.shape[1]
        R = self.cast(np.repeat(centers, nr, axis=0), dirs.reshape(-1, 3), np.repeat(radii, nr)).reshape(len(centers), nr)
        ratio = R[:, -1] / np.mean(R[:, :-1], axis=1)
        ratio = np.where(np.isfinite(ratio), ratio, -np.inf)
        out = {}
        for n_job, (bi, side, back) in enumerate(jobs):
            rj = ratio[owner == n_job]
            deep = np.flatnonzero(rj >= opt.ends.dome_depth)
            out[(bi, side)] = float(back[deep[0]] if len(deep) else back[int(np.argmax(rj))])
        return out


    def _apply_clearance(self):
        opt, sk = self.opt, self.topo.sk
        for bi, br in enumerate(self.topo.branches):
            if br.kinds == [JUNCTION, JUNCTION] and br.nodes[0] != br.nodes[-1] and self._slack(bi) < 0:
                self.topo.crowded.add(bi)
            lo, hi = 0.0, br.arc[-1]
            rb = float(np.median(sk.radii[br.nodes]))
            for side in (0, 1):
                if br.kinds[side] != JUNCTION:
                    continue
                need = max(self.placed.clear.get((bi, side), 0.0), self._junction_reach(bi, side) + (opt.junction.junction_margin + br.margin[side]) * rb)
                if side == 0:
                    lo = need
                else:
                    hi = br.arc[-1] - need
            # closed ends' sections stand back from the dome (:meth:`_dome_retreat`)
            ends = br.arc.copy()
            ends[0] += self.placed.retreat.get((bi, 0), 0.0)
            ends[-1] -= self.placed.retreat.get((bi, 1), 0.0)
            if br.kinds == [JUNCTION, CLOSED] and ends[-1] - 0.3 * rb <= lo:
                # a short closed branch (an aneurysm sac on its parent): the junction's
                # half-sections need the room the dome's retreat took; the dome gets flatter
                # rather than the sections between them standing inside the half-sections.
                # A one-segment branch too: its dome's section is the only one there is.
                # ``dome_keep`` keeps it off the endpoint (not behind ``lo``): on a dome's
                # tip the section's rays run along the wall and its cap has no height
                top = br.arc[-1] - min(opt.ends.dome_keep * rb, max(br.arc[-1] - lo, 0.0))
                ends[-1] = min(top, lo + (0.3 + DOME_YIELD_ROOM) * rb)
                self.placed.retreat[(bi, 1)] = float(br.arc[-1] - ends[-1])
            if br.kinds[1] in (OPEN, CLOSED):
                hi = ends[-1] - 0.3 * rb
            if br.kinds[0] in (OPEN, CLOSED):
                lo = max(lo, ends[0] + 0.3 * rb)
            br.s, room = redistribute_sections(ends, lo, hi)
            if not room and br.kinds == [JUNCTION, CLOSED]:
                # a closed branch shorter than its junction needs: the sections between
                # stand between the half-sections' reach and the end section (thin blocks),
                # not at their nodes inside the half-sections (g0008 extracted's sac). A
                # short open branch is left as it was: where its blocks stay invalid it is
                # a stub, cut back into its parent (:mod:`.stubs`)
                reach = max(0.0, self._junction_reach(bi, 0))
                if ends[-1] > reach:
                    K = len(br.nodes) - 1
                    br.s[1:-1] = reach + (ends[-1] - reach) * np.arange(1, K) / K
            elif not room and self.opt.last.spread_tight and br.kinds == [JUNCTION, JUNCTION] and br.nodes[0] != br.nodes[-1]:
                # build_blocks' last try: a branch between two junctions without room has
                # its sections between the two junctions' bounded reaches (thin blocks)
                # instead of at their nodes inside the half-sections. Not by default: some
                # such branches build with their sections at the nodes (g0002 extracted's
                # branch between nodes 5 and 25), and in the fix loop it took the
                # stuck-end straightening from an aorta whose build needs it
                # (docs/junctions.md, h11/gbuild2)
                K = len(br.nodes) - 1
                a = self._bounded_reach(bi, 0)
                b = br.arc[-1] - self._bounded_reach(bi, 1)
                if b > a:
                    br.s[1:-1] = a + (b - a) * np.arange(1, K) / K

    def _bounded_reach(self, bi: int, side: int) -> float:
        """The junction's reach along a branch, within ``[0, REACH_RADII * the branch's radius]``.

        A half-section bounded by the branch's wall reaches about r / tan(half-angle) along
        it (2.4 r at 45 degrees between branches); a reach measured much further comes from
        rays that ran along a touching vessel or across a wide junction (g0002 given: 4.1
        along a branch 4.5 long, 7-15 along branches 8.5-13.3 long), and sections placed
        past it would all be packed into the branch's last radius. A reach measured
        negative (behind its node) counts as none."""
        rb = float(np.median(self.topo.sk.radii[self.topo.branches[bi].nodes]))
        return float(np.clip(self._junction_reach(bi, side), 0.0, REACH_RADII * rb))


    # -- 6. frames and ray casting ------------------------------------------------------
    def section_geometry(self):
        """Centres, normals, frames and radii of every section (flat arrays) and the
        per-branch index of its sections."""
        sk, t = self.topo.sk, self.template
        sym = t.symmetry_angle
        rows = []  # per branch: (centers, normals, radii) at sections
        B = len(self.topo.branches)
        Kmax = max(len(br.nodes) for br in self.topo.branches)
        X = np.zeros((B, Kmax, 3))
        T = np.zeros((B, Kmax, 3))
        first = np.zeros((B, 3))
        counts = np.zeros(B, np.int64)
        for bi, br in enumerate(self.topo.branches):
            P = self.topo.pos[br.nodes].copy()
            N = self._node_normals(br)
            pos, nrm = polyline_at(P, br.arc, br.s, N)
            # positions exactly at unmoved nodes, and end sections on their caps
            for side, k in ((0, 0), (1, len(P) - 1)):
                if br.kinds[side] == OPEN and br.caps[side] and self.ends.caps:
                    pos[k] = np.asarray(self.ends.cap_of[int(br.nodes[k])].center, float)
            if br.straighten is not None and br.straighten.any():
                chord = cs.unit(np.gradient(pos, axis=0))
                nrm = (1 - br.straighten[:, None]) * nrm + br.straighten[:, None] * chord
            nrm = cs.unit(nrm)
            _, rad = polyline_at(P, br.arc, br.s, sk.radii[br.nodes])
            K = len(P)
            X[bi, :K], T[bi, :K], counts[bi] = pos, nrm, K
            if br.kinds[0] == JUNCTION:
                T[bi, 0] = cs.unit(pos[1] - pos[0])
                first[bi] = self.topo.junctions[int(br.nodes[0])].u
            else:
                first[bi] = cs.any_perpendicular(nrm[:1])[0]
            if br.kinds[1] == JUNCTION:
                T[bi, K - 1] = cs.unit(pos[-1] - pos[-2])
            rows.append(rad)
        E1 = cs.transport_frames(X, T, first, counts)
        twist_total = np.zeros(B)
        for bi, br in enumerate(self.topo.branches):
            K = counts[bi]
            if br.kinds[1] == JUNCTION or br.kinds[1] == CYCLE:
                target = self.topo.junctions[int(br.nodes[-1])].u if br.kinds[1] == JUNCTION else E1[bi, 0]
                phi, _ = cs.residual_twist(E1[bi, K - 1][None], target[None], T[bi, K - 1][None], sym)
                twist_total[bi] = phi[0]
                s = br.s - br.s[0]
                frac = s / max(s[-1], 1e-300)
                E1[bi, :K] = cs.rotate_about(E1[bi, :K], T[bi, :K], twist_total[bi] * frac)
        f = self.frames
        f.X, f.T, f.E1, f.counts, f.R_node = X, T, E1, counts, rows
        # twist between consecutive sections (after spreading) for the report
        tw = []
        for bi, br in enumerate(self.topo.branches):
            K = counts[bi]
            if K >= 2:
                s = br.s - br.s[0]
                tw.append(np.abs(twist_total[bi]) * np.diff(s) / max(s[-1], 1e-300))
        self.frames.max_twist = float(np.degrees(np.concatenate(tw).max())) if tw else 0.0


    def cast(self, origins, directions, scale, reach: float = RAY_REACH) -> np.ndarray:
        """:func:`~vmesh.geometry.rays.cast_rays` through the build's ray cache
        (:class:`~vmesh.geometry.rays.RayCache`, ``self.work.rays``): a section that did not
        move is cast once per build."""
        return self.work.rays.cast(self.sdf, origins, directions, scale, reach=reach, intersect_lines=self.intersect_lines)


    def regular_sections(self):
        """Vertices of every regular (non-junction) section."""
        t = self.template
        idx = []  # (branch, k)
        for bi, br in enumerate(self.topo.branches):
            K = len(br.nodes)
            for k in range(K):
                side = 0 if k == 0 else (1 if k == K - 1 else -1)
                if side >= 0 and br.kinds[side] == JUNCTION:
                    continue
                if k == K - 1 and br.kinds[1] == CYCLE:
                    continue  # the same section as k = 0
                idx.append((bi, k))
        bi_arr = np.array([i for i, _ in idx])
        k_arr = np.array([k for _, k in idx])
        C = self.frames.X[bi_arr, k_arr]
        Nn = self.frames.T[bi_arr, k_arr]
        E1 = cs.unit(cs.reject(self.frames.E1[bi_arr, k_arr], Nn))
        E2 = np.cross(Nn, E1)
        rad = np.array([self.frames.R_node[b][k] for b, k in idx])
        # which way is out at end sections
        outward = np.zeros(len(idx))
        for n, (b, k) in enumerate(idx):
            br = self.topo.branches[b]
            if k == 0 and br.kinds[0] in (OPEN, CLOSED):
                outward[n] = -1.0
            elif k == len(br.nodes) - 1 and br.kinds[1] in (OPEN, CLOSED):
                outward[n] = 1.0
        # flat caps give the signed distance no sign on their plane: cast from just inside
        is_open = np.array([(k == 0 and self.topo.branches[b].kinds[0] == OPEN) or
                            (k == len(self.topo.branches[b].nodes) - 1 and self.topo.branches[b].kinds[1] == OPEN) for b, k in idx])
        ang = t.ray_angles
        C = C - self._behind_notches(idx, C, Nn * outward[:, None], E1, E2, rad, is_open)[:, None] * Nn * outward[:, None]
        shift = (OPEN_END_SHIFT * rad * outward * is_open)[:, None] * Nn
        origin = C - shift
        dirs = cs.ray_directions(E1, E2, ang)
        R = self.cast(np.repeat(origin, len(ang), axis=0), dirs.reshape(-1, 3), np.repeat(rad, len(ang))).reshape(len(idx), -1)
        R = self._own_territory(idx, origin, dirs, R, rad)
        R = self._through_necks(idx, origin, dirs, R, rad, is_open)
        if self.opt.ends.short_end_rays > 0:
            C, R = self._back_from_short_rays(idx, C, origin, dirs, R, rad, is_open, Nn * outward[:, None])
        if np.any(~np.isfinite(R)):
            lost = np.flatnonzero(~np.all(np.isfinite(R), axis=1))
            b, k = idx[int(lost[0])]
            node = int(self.topo.branches[b].nodes[k])
            message = f"cross-section at skeleton node {node} finds no wall within reach (is the node inside the vessel?)"
            # a side branch cut open within its junction's half-sections (a stub) has its
            # cap section in the parent's wall: rays in the cap's plane run along that wall
            stubs = {bi: self.stub_of(bi) for bi in sorted({idx[n][0] for n in lost.tolist()})}
            if all(s is not None for s in stubs.values()):
                failure = _Failure(message, None, np.zeros(0, np.int64), self.topo.sk, [], [], "")
                failure.stubs = list(stubs.values())
                raise failure
            raise MeshingError(message)
        lc = np.array([self._layer_and_core((b, k)) for b, k in idx]).reshape(-1, 2)
        V = cs.section_vertices(t, C, E1, E2, R, lc[:, 1], lc[:, 0])
        on_surface = np.zeros(V.shape[:2], bool)
        on_surface[:, t.kind == cs.VERTEX_OUTER] = True
        # closed ends: the section stays flat; the dome beyond it is closed by a cap of blocks
        self.frames.domes = []
        for n, (b, k) in enumerate(idx):
            br = self.topo.branches[b]
            if (k == 0 and br.kinds[0] == CLOSED) or (k == len(br.nodes) - 1 and br.kinds[1] == CLOSED):
                self.frames.domes.append(self._dome_cap(n, int(br.nodes[k]), C[n], V[n], Nn[n] * outward[n], rad[n], lc[n, 0], lc[n, 1]))
        return idx, V, on_surface, R


    def _behind_notches(self, idx, C, out, E1, E2, rad, is_open) -> np.ndarray:
        """How far (n,) each open end's section moves back from its cap's plane so that its
        rays reach the wall, not the cap.

        A hand-cut open end has a rim that wanders along the vessel; its cap
        (:func:`vmesh.preprocess.cap_loop`) is the cone from that rim to its centroid, which
        crosses the cap's plane short of the wall at every azimuth where the rim dips behind
        the plane (a ray there stops at a few tenths of the radius, and the blocks behind the
        section fold). The ray at azimuth ``a`` meets the cone near the generator from the
        rim at ``a``; the section moves back (along the cap's normal) behind the deepest of
        the rim's notches within half a ray spacing of its rays, less the rays' start
        ``OPEN_END_SHIFT`` radii inside, and at most half way back to the previous section.
        A planar rim keeps its section on the cap."""
        back = np.zeros(len(idx))
        if not self.ends.caps:
            return back
        ang = self.template.ray_angles
        for n in np.flatnonzero(is_open):
            b, k = idx[n]
            br = self.topo.branches[b]
            cap = self.ends.cap_of.get(int(br.nodes[k]))
            rim = np.zeros((0, 3)) if cap is None or getattr(cap, "rim", None) is None else np.asarray(cap.rim, float)
            if len(rim) < 3:
                continue
            rel = rim - C[n]
            phi = np.arctan2(rel @ E2[n], rel @ E1[n])
            # the rim within half a ray spacing of each ray (the cone's apex, the rim's
            # centroid, is near but not on the section's centre)
            near = np.abs(np.angle(np.exp(1j * (phi[None, :] - ang[:, None])))) <= np.pi / len(ang)
            h = np.where(near, (rel @ out[n])[None, :], np.inf).min(axis=1)
            need = -float(h[np.isfinite(h)].min(initial=0.0)) - OPEN_END_SHIFT * float(rad[n])
            if need <= 0:
                continue
            prev = self.frames.X[b, 1 if k == 0 else k - 1]
            back[n] = min(need, 0.5 * abs(float((C[n] - prev) @ out[n])))
        return back


    def _back_from_short_rays(self, idx, C, origin, dirs, R, rad, is_open, out):
        """Open ends' sections whose rays reach less than ``ends.short_end_rays`` of the
        previous section's at the same azimuth move half way back towards it (along the
        outward normal ``out``), kept where their shortest share rises: the end's own plane
        can run along the wall (a flat closed end taken for an opening, whose section stands
        in the end's plane; a voxel staircase's terraces by it), and the boundary layer between
        a round section and a cut-short one folds (s1 g0010 given: wall vertices 0.09-0.71 from
        the end node against 0.63-0.71 one section before). Returns the new centres and rays."""
        where = {key: n for n, key in enumerate(idx)}
        C, R = C.copy(), R.copy()
        for n in np.flatnonzero(is_open).tolist():
            b, k = idx[n]
            p = where.get((b, 1 if k == 0 else k - 1))
            if p is None:
                continue
            share = R[n] / np.maximum(R[p], 1e-300)
            if not np.all(np.isfinite(share)) or share.min() >= self.opt.ends.short_end_rays:
                continue
            back = 0.5 * abs(float((C[n] - C[p]) @ out[n]))
            o = origin[n] - back * out[n]
            r = self.cast(np.repeat(o[None], len(dirs[n]), axis=0), dirs[n], np.full(len(dirs[n]), rad[n]))
            r = self._own_territory([idx[n]], o[None], dirs[n : n + 1], r[None], rad[n : n + 1])[0]
            if np.all(np.isfinite(r)) and (r / np.maximum(R[p], 1e-300)).min() > share.min():
                C[n], R[n] = C[n] - back * out[n], r
        return C, R


    def _through_necks(self, idx, origin, dirs, R, rad, is_open) -> np.ndarray:
        """Rays with no wall within reach cut where they slip through a neck into a fused
        lumen (:func:`~vmesh.geometry.rays.cut_at_necks`); others stay as they are. Not at
        open ends, whose rays start just inside the cap (no lumen's depth to compare the
        neck with), nor on a stub's branch, whose cap section lies in its parent's wall:
        the builder cuts the stub instead."""
        lost = np.argwhere(~np.isfinite(R))
        stub = {b: self.stub_of(b) is not None for b in {idx[n][0] for n in lost[:, 0].tolist()}}
        lost = lost[[not is_open[n] and not stub[idx[n][0]] for n in lost[:, 0].tolist()]] if len(lost) else lost
        if len(lost) == 0:
            return R
        R = R.copy()
        R[lost[:, 0], lost[:, 1]] = cut_at_necks(self.sdf, origin[lost[:, 0]], dirs[lost[:, 0], lost[:, 1]], rad[lost[:, 0]])
        return R


    def _own_territory(self, idx, origin, dirs, R, rad) -> np.ndarray:
        """Section rays cut where they cross into a touching vessel
        (:func:`~vmesh.geometry.rays.clip_to_territory`): a skeleton point is foreign to a
        section when the way to it along the skeleton is longer than the straight way by
        more than twice both radii (another vessel that touches this one, or this one
        curled back onto itself), not a neighbour along the tree.

        The skeleton's tubes and ways and the cuts of rays clipped before are kept while
        the skeleton stays as it is (:class:`~.prep.Territory`): a fix round that moves a
        few sections clips only their rays."""
        if not self.opt.section.own_territory:
            return R
        ter = self._territory()
        if ter.tree is None:
            return R
        na = R.shape[1]
        Q, rq, q_node, q_off = ter.Q, ter.rq, ter.q_node, ter.q_off
        node = np.array([self.topo.branches[b].nodes[k] for b, k in idx])
        o = np.repeat(origin, na, axis=0)
        d = dirs.reshape(-1, 3)
        r = np.repeat(rad, na)
        lengths = R.ravel()
        rows = np.column_stack([o, d, lengths, r, np.repeat(node, na)])
        out, found = ter.cuts.find(rows)
        miss = np.flatnonzero(~found)
        if len(miss) == 0:
            return out.reshape(R.shape)
        sec = miss // na
        start = np.linalg.norm(origin[sec] - self.topo.pos[node[sec]], axis=1)
        # A way longer than ``need`` is foreign whatever its value: a tested sample lies
        # within its radius of a point on the ray, so its straight way is at most the ray's
        # length plus its radius, and the way along the skeleton less the sample's and the
        # section's offsets would still exceed it by both radii twice. Ways beyond the reach
        # may read inf, and any longer reach gives the same cuts: each ray's cut depends on
        # that ray alone (and is kept), and each section's node is searched only as far as
        # its own rays need.
        reach = np.nan_to_num(lengths[miss]) + 2.0 * r[miss] + start  # + the sample's 3 rq + q_off
        ways = ter.ways

        def foreign(rays, samples):
            # the least the way from the section's centre to the sample can be
            need = reach[rays] + 3.0 * rq[samples] + q_off[samples]
            way = ways(node[sec[rays]], q_node[samples], need) - q_off[samples] - start[rays]
            return way > np.linalg.norm(o[miss[rays]] - Q[samples], axis=1) + 2.0 * (r[miss[rays]] + rq[samples])

        touched = self.opt.ends.touched_caps  # open ends in a contact: their tubes end at their caps' planes
        if touched and touched not in ter.ended:  # once per territory, not per section
            ter.ended[touched] = ended_at_touched_caps(ter, self.topo, self.ends.cap_of, touched)
        ended = ter.ended[touched] if touched else None
        out[miss] = clip_to_territory(o[miss], d[miss], lengths[miss], r[miss], foreign, (Q, rq), tree=ter.tree, ended=ended)
        keep = miss[np.isfinite(lengths[miss])]  # nan never matches a row: not kept
        ter.cuts.add(rows[keep], out[keep])
        return out.reshape(R.shape)


    def _territory(self) -> Territory:
        """The kept :class:`~.prep.Territory` of the current skeleton (a new one when its
        branches, node positions, radii or segments changed; where only some nodes
        moved, with the cuts of the rays far from them)."""
        sk, branches = self.topo.sk, self.topo.branches
        key = Territory.key_of(branches, self.topo.pos, sk.radii, sk.edges)
        ter = self.topo.territory
        if ter is None or ter.key != key:
            new = Territory(branches, self.topo.pos, sk.radii, sk.edges)
            if ter is not None:
                new.inherit(ter)  # a junction moved: the cuts far from it stay
            ter = self.topo.territory = new
        return ter


    def _dome_cap(self, n: int, node: int, c: np.ndarray, V: np.ndarray, d: np.ndarray, rad: float, layer: float, core: float) -> dict:
        """Corners of the cap of blocks that closes the dome beyond a closed end's flat section.

        A closed end's boundary layer has to turn round the dome with the wall: blocks with
        a side face and an end face both on the smooth dome would meet it at a straight
        angle and fold their elements there. The cap is the upper half of a ball's O-grid
        (a cube projected onto the sphere) standing on the section: the section's core
        square is lifted along the outward axis ``d`` by ``core`` times the wall distance
        ahead (``lifted``), and rays from the section centre ``c`` through the lifted
        corners find the dome (``wall``) and the boundary layer's inner surface at
        ``1 - layer`` of the way (``inner``), as rays in the section plane place its ring
        and outer corners. The assembly joins the core square to ``lifted`` (the cap's core),
        ``lifted`` to ``inner`` and the section's ring quads to both (the cap's ring), and
        ``inner`` to ``wall`` and the section's boundary-layer quads to both (the boundary
        layer over the dome, continuing the side wall's).

        Returns
        -------
        dict with ``section`` (index of the end section), ``core`` (template core vertices)
        and their ``lifted``, ``inner`` and ``wall`` positions ((len(core), 3) each).
        """
        t = self.template
        core_v = np.flatnonzero(t.kind == cs.VERTEX_CORE)
        ahead = self.cast(c[None], d[None], np.array([rad]))[0]
        if not np.isfinite(ahead):
            raise MeshingError(f"closed end at skeleton node {node}: no wall found ahead of its cross-section")
        lifted = V[core_v] + core * ahead * d
        dirs = cs.unit(lifted - c)
        R = self.cast(np.repeat(c[None], len(dirs), 0), dirs, np.full(len(dirs), rad))
        if np.any(~np.isfinite(R)):
            raise MeshingError(f"closed end at skeleton node {node}: no wall found round the dome beyond its cross-section")
        return {"section": n, "core": core_v, "lifted": lifted,
                "inner": c + ((1.0 - layer) * R)[:, None] * dirs, "wall": c + R[:, None] * dirs}


def _clear_from(ok: np.ndarray, s: np.ndarray, rb: float) -> int:
    """Index of the first candidate (arc lengths ``s`` from a junction, ``ok`` where every
    ray is short) from which sections are clear of the junction: after the last candidate
    that is not, unless a clean stretch of at least one branch radius lies between: rays
    long again beyond it are the branch's own (a bend curling back, a vessel passing),
    not the junction's, and sections pushed past them would stand in that bend (a branch
    curling back 3-4 radii from its 4-junction: docs/junctions.md, h12/realbuild)."""
    bad = np.flatnonzero(~ok)
    if len(bad) == 0:
        return 0
    run = np.r_[bad[np.flatnonzero(np.diff(bad) > 1)], bad[-1]]  # last index of each unclean run
    for end in run[:-1]:
        nxt = bad[bad > end][0]  # where the next unclean run starts
        if s[nxt - 1] - s[end + 1] >= rb:
            return int(end + 1)
    return int(bad[-1] + 1)
