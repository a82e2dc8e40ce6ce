"""Assembly of the sections and half-sections into hexahedral blocks (step 4 of the method)."""

from __future__ import annotations

import numpy as np

from ...blocks import (
    AXIS_ALONG,
    AXIS_LAYER,
    AXIS_RING,
    FACE_INTERIOR,
    FACE_WALL,
    LAYER_BOUNDARY,
    LAYER_CORE,
    LAYER_RING,
    BlockStructure,
    hex_corner_jacobians,
)
from .. import cross_sections as cs
from .options import CYCLE, JUNCTION, OPEN


class _Assembly:
    """Assembly step of the block builder: sections and half-sections joined into
    blocks. Mixed into :class:`~vmesh.geometry.blocks.builder._Builder`, whose state
    they share."""

    # -- 7. assembly ------------------------------------------------------------------
    def assemble(self) -> BlockStructure:
        """The block structure of the current state: vertices of every section, half-section
        and dome cap, blocks along every branch and round every dome, mirrored blocks flipped."""
        self.work.charge()  # the build's budget counts whole assemblies (:mod:`.work`)
        t = self.template
        idx, sec_ids, vertices, on_surface = self._assemble_vertices()
        rows = [[] for _ in range(9)]  # hexes, fb, ak, radius, bnode, bseg, blayer, btags, where
        columns = self._branch_blocks(sec_ids, rows)
        self._dome_blocks(idx, sec_ids, rows)
        hexes, fb, ak, radius, bnode, bseg, blayer, btags, where = rows
        hexes = np.vstack(hexes)
        fb = np.vstack(fb)
        ak = np.vstack(ak)
        # blocks whose every corner is negative are only mirrored: flip them along k
        J = self._corner_jacobians(vertices, hexes)
        flip = np.all(J < 0, axis=1)
        if flip.any():
            hexes[flip] = hexes[flip][:, [4, 5, 6, 7, 0, 1, 2, 3]]
            fb[flip] = fb[flip][:, [0, 1, 2, 3, 5, 4]]
            # a block flipped along k has the negated Jacobians of its mirrored corners (exactly)
            J[flip] = -J[flip][:, [4, 5, 6, 7, 0, 1, 2, 3]]
        self.built.corners = J
        self.built.block_where = np.vstack(where)
        self.built.block_layers = np.concatenate(blayer)
        # duplicates: a keyword construction, like the filters' option objects; no shared logic
        blocks = BlockStructure(
            vertices=vertices,
            hexes=hexes,
            vertex_on_surface=on_surface,
            face_boundary=fb,
            axis_kind=ak,
            block_radius=np.concatenate(radius),
            block_node=np.concatenate(bnode),
            block_segment=np.concatenate(bseg),
            block_layer=np.concatenate(blayer),
            block_tags=btags,
            boundary_names=dict(self.ends.boundary_names),
        )
        blocks.info["_columns"] = columns  # this structure's own section ids (:mod:`.crotch`), dropped by finish
        self.built.info = {
            "blocks_around": t.n_around,
            "core": [t.a, t.b],
            "max_twist_deg": round(self.frames.max_twist, 3),
            "branches": len(self.topo.branches),
            "junctions": {int(c): {"neighbors": j.neighbors.tolist(), "axis": j.u.round(6).tolist(),
                                   "rotation_deg": np.degrees(j.psi).round(2).tolist()} for c, j in self.topo.junctions.items()},
            "flipped_blocks": int(flip.sum()),
            "dome_caps": len(self.frames.domes),
            "dome_retreat": {int(self.topo.branches[bi].nodes[-1 if side else 0]): round(v, 4) for (bi, side), v in self.placed.retreat.items()},
            "skeleton": self.topo.sk,
        }
        return blocks

    def _corner_jacobians(self, vertices: np.ndarray, hexes: np.ndarray) -> np.ndarray:
        """Corner Jacobians of ``hexes`` (before flipping). Where the last assembly had the
        same blocks (a fix round moves sections, it keeps their numbering), only blocks with a
        moved corner are computed again: a fix at one junction of a tree of thousands of
        sections re-checks that junction's blocks, not the tree's."""
        last = self.built.unflipped
        if last is not None and last[0].shape == vertices.shape and np.array_equal(last[1], hexes):
            moved = np.any(vertices != last[0], axis=1)
            redo = np.flatnonzero(moved[hexes].any(axis=1))
            J = last[2].copy()
            J[redo] = hex_corner_jacobians(vertices[hexes[redo]])
        else:
            J = hex_corner_jacobians(vertices[hexes])
        self.built.unflipped = (vertices.copy(), hexes.copy(), J.copy())
        return J

    def _assemble_vertices(self):
        """Vertices of the regular sections, the junctions' spines and half-sections and the
        dome caps (which get their global ids), with the regular sections' keys and ids."""
        t = self.template
        self.section_geometry()
        nv_t = t.n_vertices
        verts, on_surf = [], []
        n_vert = 0
        # regular sections
        idx, V, S, _ = self.regular_sections()
        sec_ids = {}
        for n, key in enumerate(idx):
            sec_ids[key] = n_vert + np.arange(nv_t)
            n_vert += nv_t
        verts.append(V.reshape(-1, 3))
        on_surf.append(S.reshape(-1))
        # junctions: spine + upper halves
        upper, spine = t.upper, t.spine
        for c, j in self.topo.junctions.items():
            m = len(j.neighbors)
            sdirs = j.separator_dir(np.arange(m))
            R = self._half_rays(j, sdirs)
            layer, core = self._layer_and_core(("J", c))
            HV = self._half_vertices(j, sdirs, R, core, layer)
            j.spine_ids = np.full(nv_t, -1, np.int64)
            j.spine_ids[spine] = n_vert + np.arange(spine.sum())
            verts.append(HV[0, spine])
            on_surf.append(t.kind[spine] == cs.VERTEX_OUTER)
            n_vert += int(spine.sum())
            only_up = upper & ~spine
            j.half_ids = np.full((m, nv_t), -1, np.int64)
            for h in range(m):
                j.half_ids[h, spine] = j.spine_ids[spine]
                j.half_ids[h, only_up] = n_vert + np.arange(only_up.sum())
                n_vert += int(only_up.sum())
                verts.append(HV[h, only_up])
                on_surf.append(t.kind[only_up] == cs.VERTEX_OUTER)
        # dome caps: the lifted core square, and its rays' points on the layer and the dome
        for dome in self.frames.domes:
            cv = dome["core"]
            for name, onwall in (("lifted", False), ("inner", False), ("wall", True)):
                dome[name + "_ids"] = np.full(nv_t, -1, np.int64)
                dome[name + "_ids"][cv] = n_vert + np.arange(len(cv))
                n_vert += len(cv)
                verts.append(dome[name])
                on_surf.append(np.full(len(cv), onwall))
        vertices = np.vstack(verts)
        on_surface = np.concatenate(on_surf)
        return idx, sec_ids, vertices, on_surface

    def _branch_blocks(self, sec_ids: dict, rows: list) -> tuple:
        """Append the blocks between consecutive sections of every branch to ``rows``;
        return each branch's section ids (K, nv), first block row and end kinds."""
        t, sk = self.template, self.topo.sk
        hexes, fb, ak, radius, bnode, bseg, blayer, btags, where = rows
        q = t.quads
        nq = len(q)
        columns = ([], [], [])
        n_blocks = 0
        for bi, br in enumerate(self.topo.branches):
            K = len(br.nodes)
            ids = [None] * K
            for k in range(K):
                side = 0 if k == 0 else (1 if k == K - 1 else -1)
                if side >= 0 and br.kinds[side] == JUNCTION:
                    ids[k] = self._folded_ids(bi, side)
                elif k == K - 1 and br.kinds[1] == CYCLE:
                    ids[k] = self._cycle_close_ids(bi, sec_ids[(bi, 0)])
                else:
                    ids[k] = sec_ids[(bi, k)]
            # all segments of the branch at once, in the order segment by segment, quad by quad
            ids = np.stack(ids)  # (K, nv)
            m = K - 1
            columns[0].append(ids)
            columns[1].append(n_blocks)
            columns[2].append(tuple(br.kinds))
            n_blocks += m * nq
            hexes.append(np.concatenate([ids[:-1][:, q], ids[1:][:, q]], axis=2).reshape(-1, 8))
            f = np.full((m, nq, 6), FACE_INTERIOR, np.int64)
            f[:, t.quad_wall, 1] = FACE_WALL
            # open ends lie on their caps; closed ends are shared with their dome's cap blocks
            if br.kinds[0] == OPEN:
                f[0, :, 4] = br.caps[0]
            if br.kinds[1] == OPEN:
                f[m - 1, :, 5] = br.caps[1]
            fb.append(f.reshape(-1, 6))
            ak.append(np.tile(np.c_[t.quad_axes, np.full(nq, AXIS_ALONG)], (m, 1)))
            R = np.asarray(self.frames.R_node[bi][:K], float)
            radius.append(np.repeat(0.5 * (R[:-1] + R[1:]), nq))
            bnode.append(np.repeat(np.asarray(br.nodes[:-1], np.int64), nq))
            bseg.append(np.repeat(np.asarray(br.edges, np.int64), nq))
            blayer.append(np.tile(t.quad_layer, m))
            for k in range(m):
                n0, n1, e = int(br.nodes[k]), int(br.nodes[k + 1]), int(br.edges[k])
                tags = tuple(sorted(set(sk.node_tags[n0]) | set(sk.node_tags[n1]) | set(sk.edge_tags[e])))
                btags.extend([tags] * nq)
            where.append(np.c_[np.full(m * nq, bi), np.repeat(np.arange(m), nq)])
        return columns

    def _dome_blocks(self, idx: list, sec_ids: dict, rows: list) -> None:
        """Append the cap blocks round every closed end's dome to ``rows``."""
        t, sk = self.template, self.topo.sk
        nv_t = t.n_vertices
        q = t.quads
        hexes, fb, ak, radius, bnode, bseg, blayer, btags, where = rows
        loop_of = np.full(nv_t, -1, np.int64)  # ring and outer vertices -> the loop vertex on their ray
        loop_of[t.ring] = t.loop
        loop_of[t.outer] = t.loop
        for dome in self.frames.domes:
            bi, k = idx[dome["section"]]
            br = self.topo.branches[bi]
            kseg = 0 if k == 0 else k - 1
            E, L, I, W = sec_ids[(bi, k)], dome["lifted_ids"], dome["inner_ids"], dome["wall_ids"]
            cq, rq, bq = (q[t.quad_layer == lay] for lay in (LAYER_CORE, LAYER_RING, LAYER_BOUNDARY))
            ax_c, ax_r, ax_b = (t.quad_axes[t.quad_layer == lay] for lay in (LAYER_CORE, LAYER_RING, LAYER_BOUNDARY))
            lb = loop_of[bq]  # ring quads start and end on loop vertices already
            blocks_ = [
                # the cap's core: the section's core square lifted along the axis
                (np.hstack([E[cq], L[cq]]), np.c_[ax_c, np.full(len(cq), AXIS_ALONG)], LAYER_CORE, False),
                # the cap's ring over the core, and round it from the section's ring quads
                (np.hstack([L[cq], I[cq]]), np.c_[ax_c, np.full(len(cq), AXIS_RING)], LAYER_RING, False),
                (np.hstack([E[rq], np.stack([L[rq[:, 0]], I[rq[:, 0]], I[rq[:, 3]], L[rq[:, 3]]], 1)]), np.c_[ax_r, np.full(len(rq), AXIS_ALONG)], LAYER_RING, False),
                # the boundary layer over the dome (across its first axis, wall face 1 as in the
                # ring's layer) and round it from the section's boundary-layer quads
                (np.stack([I[cq[:, 0]], W[cq[:, 0]], W[cq[:, 1]], I[cq[:, 1]], I[cq[:, 3]], W[cq[:, 3]], W[cq[:, 2]], I[cq[:, 2]]], 1),
                 np.c_[np.full(len(cq), AXIS_LAYER), ax_c], LAYER_BOUNDARY, True),
                (np.hstack([E[bq], np.stack([I[lb[:, 0]], W[lb[:, 0]], W[lb[:, 3]], I[lb[:, 3]]], 1)]), np.c_[ax_b, np.full(len(bq), AXIS_ALONG)], LAYER_BOUNDARY, True),
            ]
            n0, n1 = int(br.nodes[kseg]), int(br.nodes[kseg + 1])
            e = int(br.edges[kseg])
            tags = tuple(sorted(set(sk.node_tags[n0]) | set(sk.node_tags[n1]) | set(sk.edge_tags[e])))
            for hx, axes, lay, on_wall in blocks_:
                m = len(hx)
                hexes.append(hx)
                f = np.full((m, 6), FACE_INTERIOR, np.int64)
                if on_wall:
                    f[:, 1] = FACE_WALL
                fb.append(f)
                ak.append(axes)
                radius.append(np.full(m, self.frames.R_node[bi][k]))
                bnode.append(np.full(m, n0))
                bseg.append(np.full(m, e))
                blayer.append(np.full(m, lay))
                btags.extend([tags] * m)
                where.append(np.c_[np.full(m, bi), np.full(m, kseg)])

    def _folded_ids(self, bi: int, side: int) -> np.ndarray:
        """Global vertex id of each template vertex of a branch's end section at a junction."""
        t = self.template
        br = self.topo.branches[bi]
        K = len(br.nodes)
        k = 0 if side == 0 else K - 1
        c = int(br.nodes[k])
        j = self.topo.junctions[c]
        h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
        m = len(j.neighbors)
        n = self.frames.T[bi, k]
        e1 = self.frames.E1[bi, k]
        E1 = cs.unit(cs.reject(j.u[None], n[None]))[0]
        E2 = np.cross(n, E1)
        rho = cs.signed_angle(E1[None], e1[None], n[None])[0]
        perm = min(t.symmetries, key=lambda s: abs(np.angle(np.exp(1j * (s[0] - rho)))))[1]
        canon = perm  # template vertex -> canonical vertex
        seps = [(h - 1) % m, h]
        s_dirs = j.separator_dir(np.array(seps))
        up_first = (s_dirs[0] @ E2) >= (s_dirs[1] @ E2)
        h_up, h_low = (seps[0], seps[1]) if up_first else (seps[1], seps[0])
        y = t.xy[canon, 1]
        ids = np.where(y > 1e-12, j.half_ids[h_up, canon], j.half_ids[h_low, t.mirror[canon]])
        ids = np.where(np.abs(y) <= 1e-12, j.spine_ids[canon], ids)
        return ids


    def _cycle_close_ids(self, bi: int, first_ids: np.ndarray) -> np.ndarray:
        """Ids of a cycle's closing section: its first section seen in the transported frame."""
        t = self.template
        K = self.frames.counts[bi]
        n = self.frames.T[bi, K - 1]
        rho = cs.signed_angle(cs.reject(self.frames.E1[bi, 0][None], n[None]), self.frames.E1[bi, K - 1][None], n[None])[0]
        perm = min(t.symmetries, key=lambda s: abs(np.angle(np.exp(1j * (s[0] - rho)))))[1]
        return first_ids[perm]
