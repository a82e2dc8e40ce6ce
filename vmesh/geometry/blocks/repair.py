"""Repairs: invalid blocks and boundary-layer blocks that would fold on the wall (step 5 of the method)."""

from __future__ import annotations

import numpy as np

from ...blocks import LAYER_BOUNDARY, BlockStructure
from .checks import (
    FILL_CHECKS,
    _Failure,
    fill_quality,
    fill_score,
    projected_wall_quality,
)
from .crossings import STRAIGHT, STRAIGHTEN_STEP, crossing_bends
from .options import CYCLE, JUNCTION


class _Repair:
    """Repair steps of the block builder: invalid blocks, and boundary-layer blocks that
    would fold on the wall. Mixed into :class:`~vmesh.geometry.blocks.builder._Builder`,
    whose state they share."""

    # -- 8. validity -----------------------------------------------------------------------
    def relieve_wall_folds(self, blocks: BlockStructure) -> BlockStructure:
        """Re-place the first cross-sections and half-planes at junctions whose boundary
        layer would fold in the transfinite fill.

        At a junction crotch the half cross-section meets the wall obliquely: a boundary-layer
        block from it to a branch section that stands close is short on the crotch side and
        long on the other, and projecting its wall face folds it. Junctions with such blocks
        (:func:`projected_wall_quality` at most ``wall_quality``) get, per branch end, the
        extra margin of ``wall_margins`` whose blocks fill best, and where they still fold,
        the half-plane rotations whose blocks fill best, then margins again. Blocks are
        judged by filling them (:func:`fill_quality`, at the default and a finer
        resolution, without untangling); the new placement is kept only when the
        junction's blocks fill better at one resolution and no worse at any, and every
        block stays valid."""
        opt = self.opt
        quality = self._wall_quality(blocks)
        ends = self._junction_ends(np.flatnonzero(quality <= opt.repair.wall_quality))
        if not ends:
            return blocks
        nodes = sorted({int(self.topo.branches[bi].nodes[-side]) for bi, side in ends})
        near = self._junction_blocks(nodes)
        before = self._checked_score(blocks, near)
        saved = ([br.margin.copy() for br in self.topo.branches],
                 {c: (j.cand.pick.copy(), j.psi.copy()) for c, j in self.topo.junctions.items()})
        trial = self._margins_for_wall(ends)
        after = self._checked_score(trial, near)
        if np.any(after < 0):
            # still folded: turn the half-planes too, then place the first sections again
            self._rotate_for_wall(ends)
            trial = self._margins_for_wall(ends)
            after = self._checked_score(trial, near)
        if not (np.all(after >= before - 1e-9) and np.any(after > before + 1e-9)):
            # the junction's blocks fill no better at some resolution: back to where they were
            for br, m in zip(self.topo.branches, saved[0]):
                br.margin = m
            for c, (pick, psi) in saved[1].items():
                self.topo.junctions[c].cand.pick, self.topo.junctions[c].psi = pick, psi
            self._apply_clearance()
            return self.assemble()
        self.fixes.append(f"re-placed the half cross-sections and first cross-sections at junction node(s) {nodes} "
                          f"where the boundary layer would fold (fill scores {np.round(before, 3).tolist()} -> {np.round(after, 3).tolist()})")
        return trial


    def choose_centres(self, blocks: BlockStructure) -> BlockStructure:
        """Per junction, keep the half-sections' line through the wall's centre
        (:meth:`_junction_centre`) or move it back onto the skeleton node, whichever fills the
        blocks of the junction's first segments better.

        The centre shortens the crotch half-section of a node far upstream of the apex, but
        where a thin branch leaves a wide one the node can serve its first blocks better.
        Both placements are assembled once (all junctions switched together; they are
        independent), their junction blocks filled (:func:`fill_quality`, without
        untangling), and a junction switches only when it fills better at one resolution
        and no worse at any, with every block valid."""
        if self.opt.junction.junction_centre <= 0 or not self.topo.junctions:
            return blocks
        nodes = sorted(c for c in self.topo.junctions if c not in self.local.at_node)
        out, switch = self._switch_where_better(blocks, nodes, self.local.at_node)
        if switch:
            self.fixes.append(f"half cross-sections of junction node(s) {switch} meet on the node, not the wall's centre, where their blocks fill better")
        return out

    def _switch_where_better(self, blocks: BlockStructure, nodes: list, flag: set) -> tuple:
        """Add the junctions ``nodes`` to ``flag`` (a set of ``local`` the junction steps read)
        and rebuild them, all in one assembly (they are independent); each keeps the switch
        only where its first segments' blocks fill better at one resolution and no worse at
        any (:meth:`_centre_scores`), with every block valid. Returns the assembly and the
        switched nodes."""
        if not nodes:
            return blocks, []
        before = self._centre_scores(blocks, nodes)
        saved = {c: self.topo.junctions[c] for c in nodes}  # with the rotations the fixes chose
        flag |= set(nodes)
        for c in nodes:
            self._rebuild_junction(c)
        self._apply_clearance()
        trial = self.assemble()
        after = self._centre_scores(trial, nodes) if self.built.corners.min() > 0 else {c: np.full(len(FILL_CHECKS), -np.inf) for c in nodes}
        switch = [c for c in nodes if np.all(after[c] >= before[c] - 1e-9) and np.any(after[c] > before[c] + 1e-9)]
        for c in nodes:
            if c not in switch:
                self.topo.junctions[c] = saved[c]
                flag.discard(c)
        self._apply_clearance()
        out = self.assemble()
        if switch and self.built.corners.min() <= 0:
            # the junctions' choices interact: back to where they were everywhere
            for c in switch:
                self.topo.junctions[c] = saved[c]
                flag.discard(c)
            self._apply_clearance()
            return self.assemble(), []
        return out, switch

    def choose_planes(self, blocks: BlockStructure) -> BlockStructure:
        """Per n-furcation (four or more branches) whose branches leave its plane unalike,
        keep its leaning half-sections (:meth:`_leaned`) or go back to half-planes,
        whichever fills the blocks of its first segments better.

        A half-plane through the junction axis runs into a branch that dips towards a pole
        (a trifurcation's daughter out of the plane) and folds the boundary layer there;
        leaning trades that for narrower blocks next to the spine, which is not always
        better. As :meth:`choose_centres`: all such junctions get half-planes together in
        one assembly, and a junction keeps them only where that fills better at one
        resolution and no worse at any, with every block valid
        (:meth:`_switch_where_better`). 3-junctions never lean
        (their axis is the normal of their branches' tips' plane: nothing to lean for)."""
        nodes = sorted(c for c, j in self.topo.junctions.items() if self.leans(j))
        out, switch = self._switch_where_better(blocks, nodes, self.local.planar)
        if switch:
            self.fixes.append(f"half cross-sections of junction node(s) {switch} keep to half-planes, where their blocks fill better than leaning")
        return out

    def _centre_scores(self, blocks: BlockStructure, nodes) -> dict:
        """:func:`fill_score` per fill resolution of each junction's first-segment blocks."""
        near = {c: self._junction_blocks([c]) for c in nodes}
        sel = np.unique(np.concatenate(list(near.values())))
        q = np.ones((len(FILL_CHECKS), blocks.n_blocks))
        q[:, sel] = fill_quality(blocks, sel, self.project, self.sdf, self.intersect_lines, per_resolution=True)
        return {c: np.array([fill_score(row[near[c]]) for row in q]) for c in nodes}

    def lean_score(self, blocks: BlockStructure, node: int) -> np.ndarray:
        """What :func:`~.builder._choose_lean` compares at junction ``node`` of the finished
        ``blocks``, over the first-segment blocks at it and at the junctions one branch
        away: their least scaled corner Jacobian, and the least over the fill resolutions
        of their :func:`fill_score`.

        A junction's half-sections move its neighbours' first sections (through the fix
        loop's margins), so their blocks count too. Each measure alone picked the
        better-ending choice at every measured run where the choice decides a pass, and
        each missed others, mostly not the same ones (docs/junctions.md, h14/trif): the
        choice changes only where both agree."""
        from ...blocks import scaled_corner_jacobians

        near = {node}
        for bi, side in self.topo.junctions[node].ends:
            br = self.topo.branches[bi]
            if br.kinds[1 - side] == JUNCTION:
                near.add(int(br.nodes[0 if side == 1 else -1]))
        mine = self._junction_blocks(sorted(c for c in near if c in self.topo.junctions))
        corner = scaled_corner_jacobians(blocks.vertices[blocks.hexes[mine]]).min()
        fill = fill_quality(blocks, mine, self.project, self.sdf, self.intersect_lines, per_resolution=True)
        return np.array([corner, min(fill_score(row) for row in fill)])

    def _checked_score(self, blocks: BlockStructure, near: np.ndarray) -> np.ndarray:
        """:func:`fill_score` of the blocks ``near`` per fill resolution; -inf when any block
        is invalid."""
        if blocks.corner_jacobians().min() <= 0:
            return np.full(len(FILL_CHECKS), -np.inf)
        q = fill_quality(blocks, near, self.project, self.sdf, self.intersect_lines, per_resolution=True)
        return np.array([fill_score(row) for row in q])


    def _margins_for_wall(self, ends: list) -> BlockStructure:
        """Give each junction end of ``ends`` the extra margin of ``wall_margins`` whose
        first-segment blocks fill best (the least reaching ``good_wall_quality``); the ends
        are independent, so one assembly per margin scores them all. Returns the assembly."""
        opt = self.opt
        base = {e: float(self.topo.branches[e[0]].margin[e[1]]) for e in ends}
        steps = np.asarray(opt.repair.wall_margins, float)
        score = np.full((len(ends), len(steps)), -np.inf)
        for n, add in enumerate(steps):
            for bi, side in ends:
                self.topo.branches[bi].margin[side] = base[(bi, side)] + add
            self._apply_clearance()
            trial = self.assemble()
            J = self.built.corners.min(axis=1)  # trial.corner_jacobians(), kept by the assembly
            mine = [self._end_blocks(bi, side) for bi, side in ends]
            sel = np.unique(np.concatenate(mine))
            q = np.ones(trial.n_blocks)
            q[sel] = self._fill_quality(trial, sel)
            for e, (bi, side) in enumerate(ends):
                if J[self.built.block_where[:, 0] == bi].min() > 0:
                    score[e, n] = fill_score(q[mine[e]])
        pick = np.argmax(np.minimum(score, opt.repair.good_wall_quality), axis=1)
        for e, (bi, side) in enumerate(ends):
            self.topo.branches[bi].margin[side] = base[(bi, side)] + (steps[pick[e]] if np.isfinite(score[e, pick[e]]) else 0.0)
        self._apply_clearance()
        return self.assemble()


    def _junction_blocks(self, nodes) -> np.ndarray:
        """Blocks of the first segment of every branch end at the junctions ``nodes``."""
        return np.unique(np.concatenate([self._end_blocks(bi, side) for c in nodes for bi, side in self.topo.junctions[c].ends]))


    def _rotate_for_wall(self, ends: list) -> None:
        """Re-rotate the half-planes next to the junction ends ``ends`` (``(branch, side)``)
        to the candidate whose boundary-layer blocks fold least on the wall.

        A half-plane's blocks are those with a vertex of its half-section off the spine;
        all touched half-planes try their candidates in step (one assembly per candidate),
        each keeps its own best (ties: the current one), and the blocks must stay valid."""
        opt = self.opt
        seps = set()
        for bi, side in ends:
            c = int(self.topo.branches[bi].nodes[0 if side == 0 else -1])
            j = self.topo.junctions[c]
            h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
            seps |= {(c, (h - 1) % len(j.neighbors)), (c, h)}
        seps = sorted(seps)
        ncand = max(len(self.topo.junctions[c].cand.psi[sp]) for c, sp in seps)
        current = {(c, sp): int(self.topo.junctions[c].cand.pick[sp]) for c, sp in seps}
        score = np.full((len(seps), ncand), -np.inf)
        for n in range(ncand):
            for c, sp in seps:
                j = self.topo.junctions[c]
                k = n if np.isfinite(j.cand.cost[sp, n]) else current[(c, sp)]
                j.cand.pick[sp], j.psi[sp] = k, j.cand.psi[sp, k]
            self._apply_clearance()
            trial = self.assemble()
            near = np.unique(np.concatenate([self._end_blocks(bi, side) for c in {c for c, _ in seps} for bi, side in self.topo.junctions[c].ends]))
            q = np.ones(trial.n_blocks)
            q[near] = self._fill_quality(trial, near)
            # per branch its least corner Jacobian, and per half-plane its blocks: one pass
            # over the tree's blocks per candidate, not one per half-plane
            where = self.built.block_where[:, 0]
            least = np.full(len(self.topo.branches), np.inf)
            np.minimum.at(least, where, self.built.corners.min(axis=1))
            mine_of = self._half_plane_blocks(trial, seps)
            for e, (c, sp) in enumerate(seps):
                j = self.topo.junctions[c]
                if not np.isfinite(j.cand.cost[sp, n]):
                    continue
                mine = mine_of[e]
                if least[np.unique(where[mine])].min() > 0:
                    score[e, n] = fill_score(q[mine])
        for e, (c, sp) in enumerate(seps):
            j = self.topo.junctions[c]
            capped = np.minimum(score[e], opt.repair.good_wall_quality)
            k = current[(c, sp)]
            if np.isfinite(capped.max()) and capped.max() > capped[k] + 1e-3:
                k = int(np.argmax(capped))
            j.cand.pick[sp], j.psi[sp] = k, j.cand.psi[sp, k]
        self._apply_clearance()


    def _half_plane_blocks(self, blocks: BlockStructure, seps: list) -> list:
        """Per half-plane ``(junction, separator)`` of ``seps``, the blocks (sorted) with a
        vertex of its half-section off the spine. Those vertices are each half-section's
        own, so one vertex-to-half-plane map serves all of them."""
        owner = np.full(len(blocks.vertices), -1, np.int64)
        for e, (c, sp) in enumerate(seps):
            j = self.topo.junctions[c]
            own = j.half_ids[sp][j.spine_ids < 0]
            owner[own[own >= 0]] = e
        hit = owner[blocks.hexes]  # (nb, 8)
        b, corner = np.nonzero(hit >= 0)
        pairs = np.unique(np.c_[hit[b, corner], b], axis=0)  # (half-plane, block), sorted
        cut = np.searchsorted(pairs[:, 0], np.arange(len(seps) + 1))
        return [pairs[cut[e]:cut[e + 1], 1] for e in range(len(seps))]

    def _fill_quality(self, blocks: BlockStructure, subset: np.ndarray) -> np.ndarray:
        """:func:`fill_quality` of ``subset`` on this builder's wall."""
        return fill_quality(blocks, subset, self.project, self.sdf, self.intersect_lines)


    def _junction_ends(self, blocks_: np.ndarray) -> list:
        """The (branch, side) junction ends whose first segment holds any of ``blocks_``."""
        out = set()
        for bi, k in np.unique(self.built.block_where[blocks_], axis=0).tolist():
            br = self.topo.branches[bi]
            K = len(br.nodes)
            if K <= 2:
                continue
            for side, at in ((0, k == 0), (1, k == K - 2)):
                if at and br.kinds[side] == JUNCTION:
                    out.add((bi, side))
        return sorted(out)


    def _end_blocks(self, bi: int, side: int) -> np.ndarray:
        """Blocks of the segment next to a branch's end ``side``."""
        K = len(self.topo.branches[bi].nodes)
        k = 0 if side == 0 else K - 2
        return np.flatnonzero((self.built.block_where[:, 0] == bi) & (self.built.block_where[:, 1] == k))


    def thicken_layers(self, blocks: BlockStructure) -> BlockStructure:
        """Thicken the boundary layer at sections whose boundary-layer blocks would fold when
        their wall faces are projected onto the wall (:func:`projected_wall_quality`), as
        long as every block stays valid; what is left is reported in ``info``."""
        opt = self.opt
        quality = self._wall_quality(blocks)
        thickened = set()
        for _ in range(4):
            bad = np.flatnonzero(quality <= opt.repair.wall_quality)
            if len(bad) == 0:
                break
            keys = {self._section_key(bi, kk) for bi, k in self.built.block_where[bad].tolist() for kk in (k, k + 1)}
            keys = {key for key in keys if opt.section.layer_thickness * self.local.layer_scale.get(key, 1.0) < 0.5 - 1e-9}
            if not keys:
                break
            old = dict(self.local.layer_scale)
            for key in keys:
                self.local.layer_scale[key] = self.local.layer_scale.get(key, 1.0) * 1.25
            trial = self.assemble()
            if self.built.corners.min() <= 0:  # trial.corner_jacobians(), kept by the assembly
                self.local.layer_scale = old
                break
            thickened |= keys
            blocks, quality = trial, self._wall_quality(trial)
        if thickened:
            self.fixes.append(f"thickened the boundary layer at {len(thickened)} cross-section(s) where projecting the wall would fold it")
            blocks.info.update(self.built.info)
        return blocks


    def _wall_quality(self, blocks: BlockStructure) -> np.ndarray:
        """:func:`projected_wall_quality` of ``blocks``; only the wall faces whose corners
        moved since the last call are projected again (a thickening or re-placement moves
        the sections at a few junctions of a tree of thousands)."""
        return projected_wall_quality(blocks, self.project, last=self.built.wall_faces)

    def report_wall_folds(self, blocks: BlockStructure) -> None:
        """Record (and warn about) boundary-layer blocks that may still fold on the wall."""
        quality = self._wall_quality(blocks)
        self.built.info["min_projected_wall_quality"] = round(float(quality.min()), 4)
        self.built.info["blocks_folding_on_wall"] = int(np.sum(quality <= 0))
        # by id: compute_quality tells whether the mesh's worst elements lie in them
        self.built.info["wall_fold_blocks"] = np.flatnonzero(quality <= 0).tolist()
        blocks.info.update(self.built.info)
        blocks.info["fixes"] = list(self.fixes)
        if self.built.info["blocks_folding_on_wall"]:
            nodes = sorted(set(blocks.block_node[quality <= 0].tolist()))
            self.warn(f"{self.built.info['blocks_folding_on_wall']} boundary-layer block(s) next to skeleton node(s) {nodes[:8]} may fold when their faces are projected onto the wall")


    def fix(self, bad: np.ndarray, J: np.ndarray) -> bool:
        """Change the state so that the blocks ``bad`` may become valid; False when out of ideas.

        Per failing segment, in this order: shrink the core where only core and ring blocks
        fail; near a junction, move the branch's sections further away, then re-rotate the
        junction's half-planes; between two ordinary sections, straighten their planes
        towards the segment. Only when nothing of that is left and ``straighten_stuck_ends``
        is set: straighten the first sections next to the junction ends that are out of
        fixes towards their chords."""
        where = self.built.block_where[bad]
        layer = self._last_layers(bad)
        changed = moved = False
        stuck = []  # junction ends out of margins, rotations and moves
        rotated = []  # junction ends whose half-planes were re-rotated this round
        picks = {c: j.cand.pick.copy() for c, j in self.topo.junctions.items()}
        for bi, k in np.unique(where, axis=0).tolist():
            br = self.topo.branches[bi]
            K = len(br.nodes)
            sel = (where[:, 0] == bi) & (where[:, 1] == k)
            if np.all(layer[sel] != LAYER_BOUNDARY):
                shrunk = False
                for kk in (k, k + 1):
                    key = self._section_key(bi, kk)
                    sc = self.local.core_scale.get(key, 1.0)
                    if sc > 0.45:
                        self.local.core_scale[key] = sc * 0.8
                        shrunk = True
                        if key[0] == "J":
                            self._worked(key[1])
                if shrunk:
                    self.fixes.append(f"shrank the core at skeleton node {int(br.nodes[k])}")
                    changed = True
                    continue
            ends = [side for side, at in ((0, k == 0), (1, k + 1 == K - 1)) if at and br.kinds[side] == JUNCTION]
            if ends:
                for side in ends:
                    node = int(br.nodes[0 if side == 0 else -1])
                    if br.margin[side] < 2.0 and K > 2:
                        br.margin[side] += 0.5
                        self.fixes.append(f"moved the cross-sections next to junction node {node} further along its branch")
                        self._worked(node)
                        changed = True
                    elif self._rerotate(bi, side):
                        self.fixes.append(f"re-rotated the half-planes of junction node {node}")
                        self._worked(node)
                        rotated.append((bi, side, node))
                    elif self._separated(bi):
                        changed = moved = True
                        break
                    else:
                        stuck.append((bi, side, node))
                continue
            straightened = False
            for kk in (k, k + 1):
                if br.straighten[kk] < STRAIGHT:
                    br.straighten[kk] = min(1.0, br.straighten[kk] + STRAIGHTEN_STEP)
                    straightened = True
            if straightened:
                self.fixes.append(f"straightened the cross-sections at skeleton nodes {int(br.nodes[k])}-{int(br.nodes[k + 1])}")
                changed = True
        if rotated and not changed and all(np.array_equal(self.topo.junctions[n].cand.pick, picks[n]) for _, _, n in rotated):
            # two branches at one junction turned their shared half-plane back and forth:
            # the state is as it was, so every later round would give the same blocks (the
            # fix rounds used to run out on it, spending the work budget): out of ideas
            del self.fixes[len(self.fixes) - len(rotated):]
            return False
        changed = changed or bool(rotated)
        if not changed and self.opt.last.straighten_stuck_ends:
            # out of every other idea: turn the first sections at stuck junction ends
            # towards their chords (:func:`build_blocks`' last resort)
            for bi, side, node in stuck:
                if self._straighten_first(bi, side):
                    self.fixes.append(f"straightened the first cross-section next to junction node {node}")
                    self._worked(node)
                    changed = True
        if moved:
            self.placed.clear = self._clearance()
        if changed:
            self._apply_clearance()
        return changed


    def _separated(self, bi: int) -> bool:
        """:meth:`separate_junctions` of branch ``bi``, crediting the fix to the one end
        junction it moved (its position changed; the other is put back as it was)."""
        ends = [int(c) for c in (self.topo.branches[bi].nodes[0], self.topo.branches[bi].nodes[-1])]
        before = {c: self.topo.pos[c].copy() for c in ends}
        if not self.separate_junctions(bi):
            return False
        for c in ends:
            if not np.array_equal(self.topo.pos[c], before[c]):
                self._worked(c)
        return True


    def _worked(self, node: int) -> None:
        """Count one fix at junction ``node`` (what :func:`~.builder._choose_lean` compares)."""
        self.local.work_at[node] = self.local.work_at.get(node, 0) + 1


    def _straighten_first(self, bi: int, side: int) -> bool:
        """Turn the first regular section next to a branch's junction end towards the chord
        (see :meth:`section_geometry`); False when it is straight already."""
        br = self.topo.branches[bi]
        K = len(br.nodes)
        kk = 1 if side == 0 else K - 2
        if K <= 2 or br.straighten[kk] >= STRAIGHT:
            return False
        br.straighten[kk] = min(1.0, br.straighten[kk] + STRAIGHTEN_STEP)
        return True


    def _last_layers(self, bad):
        return self.built.block_layers[np.asarray(bad)]


    def _section_key(self, bi: int, k: int):
        br = self.topo.branches[bi]
        K = len(br.nodes)
        if (k == 0 and br.kinds[0] == JUNCTION) or (k == K - 1 and br.kinds[1] == JUNCTION):
            return ("J", int(br.nodes[k]))
        if k == K - 1 and br.kinds[1] == CYCLE:
            return (bi, 0)
        return (bi, k)


    def _rerotate(self, bi: int, side: int) -> bool:
        """Turn the two half-planes next to a branch so that they reach less far along it."""
        j, h, seps = self._junction_end(bi, side)
        changed = False
        for sp in seps:
            reach = j.cand.reach[sp, :, h]
            better = np.flatnonzero(reach < reach[j.cand.pick[sp]] - 1e-9 * j.radius)
            better = better[np.isfinite(j.cand.cost[sp, better])]
            if len(better):
                # the least costly of those reaching clearly less far
                target = reach[j.cand.pick[sp]] - 0.25 * (reach[j.cand.pick[sp]] - reach[better].min())
                pool = better[reach[better] <= target + 1e-12]
                pick = pool[np.argmin(j.cand.cost[sp, pool])]
                j.cand.pick[sp] = pick
                j.psi[sp] = j.cand.psi[sp, pick]
                changed = True
        return changed


    def fail(self, blocks: BlockStructure, bad: np.ndarray):
        """Raise :class:`_Failure` for the blocks ``bad``, naming the worst one's skeleton node
        and what a changed skeleton might fix: n-furcations next to the bad blocks, and
        pairs of junctions whose half cross-sections leave the branch between them no room."""
        J = blocks.corner_jacobians()
        worst = bad[np.argmin(J[bad].min(axis=1))]
        node = int(blocks.block_node[worst])
        ends = np.unique(self.topo.sk.edges[blocks.block_segment[bad]])
        nfurc = [int(c) for c in ends if self.topo.sk.degrees[c] > 3]
        crowded = []
        for bi in np.unique(self.built.block_where[bad, 0]).tolist():
            br = self.topo.branches[bi]
            a, b = int(br.nodes[0]), int(br.nodes[-1])
            if bi in self.topo.crowded and (min(a, b), max(a, b)) not in crowded:
                crowded.append((min(a, b), max(a, b)))
        hint = f"; set split_nonplanar = true to split junction node(s) {nfurc} into 3-junctions" if nfurc and not self.opt.repair.split_nonplanar else ""
        where = f" (segment {int(blocks.block_segment[worst])})"
        message = (
            f"{len(bad)} block(s) stay invalid after {len(self.fixes)} fix(es); the worst starts at skeleton node {node}{where} "
            f"with corner Jacobian {J[worst].min():.3g}"
        )
        failure = _Failure(message, blocks, bad, self.topo.sk, nfurc, crowded, hint)
        failure.stubs = self.short_stubs(bad)
        failure.bends = crossing_bends(self, bad) if self.opt.last.bend_drops > 0 else []  # opt-in (:mod:`.crossings`)
        # leaning moves only its junction's half-sections: a try failing away from every
        # leaning junction fails the same with half-planes (:func:`~.builder._fallback`)
        failure.leaned = any(self.leans(self.topo.junctions[c]) for c in ends.tolist() if c in self.topo.junctions)
        raise failure
