"""Valid blocks that are poor: lift blocks whose own corner scaled Jacobian is low.

The builder's fix loop (:meth:`~.repair._Repair.fix`) makes every block's corner Jacobians
positive and stops there. A straight block whose least corner scaled Jacobian is 0.1 is
valid, but its transfinite fill cannot be better than the block itself: the elements in
it end near that value whatever the optimisers do (docs/optimiser.md, h23/minima: blocks of
0.09-0.25 before the fill, final minima 0.18-0.26 in s1 g0008 extracted, s1 g0010 given,
s0 g0006 given). :meth:`_PoorBlocks.lift_poor_blocks` gives such blocks the same repairs as
invalid ones, round by round, and keeps a round only where the poor blocks get better and
no block gets worse than the worst before; where nothing helps, the valid structure stays
as it was (the run does not fail on it).
"""

from __future__ import annotations

import numpy as np

from ...blocks import BlockStructure, scaled_corner_jacobians
from ...errors import MeshingError
from ..quality import hex8_scaled_jacobian
from .checks import FILL_CHECKS, filled

#: Rounds of :meth:`_PoorBlocks.lift_poor_blocks`, one segment each: each is one or two
#: assemblies of the whole structure (one per repair tried: 16 at most, a tenth of the
#: default work budget of 160, so a tree that needed most of it to become valid is not held
#: up by the lift much longer).
POOR_ROUNDS = 8

#: How much the summed shortfall below the floor must fall for a round to count as
#: progress (relative): a round whose gain is rounding noise only spends an assembly.
POOR_PROGRESS = 1e-3

#: A list to record every lift trial in (``benchmarks/poor_rounds.py``), or None (the
#: default: nothing recorded, nothing filled). Each record: the segment, the repair, whether
#: it was kept, the structure's least block and shortfall before and after, and the raw fill
#: (:func:`fill_summary`) of the blocks the trial moved (:func:`moved_blocks`) before and after.
TRIAL_LOG: list | None = None

#: The optimised judge (``repair.poor_block_optimised``): the mesh optimiser's untangling
#: threshold and light-pass goal as ``mesh_transfinite`` runs them by default
#: (``untangle_below`` 0.3, ``light_pass_below`` 0.95; the untangler's smoothing up to 0.5).
OPTIMISED_UNTANGLE_BELOW, OPTIMISED_SMOOTH_BELOW, OPTIMISED_LIGHT_BELOW = 0.3, 0.5, 0.95
#: ... and its worst pass (max-min steps below the smoothing goal, then the light pass
#: again): ``worst_pass_sweeps`` 60 and ``light_pass_ratio_floor`` 0.3, the defaults.
WORST_SWEEPS, WORST_RATIO_FLOOR = 60, 0.3

#: How much the optimised least element of the moved blocks must rise for a round to be
#: kept by the optimised judge (the optimiser's own step tolerance is far smaller; below
#: this the round is noise for the run's minimum).
OPTIMISED_GAIN = 1e-3

#: Finite-difference step (x the blocks' median radius) of the wall normals the optimised
#: judge's wall nodes slide along (the builder is given the signed distance, not its gradient).
NORMAL_STEP = 1e-3


def block_scaled_jacobians(blocks: BlockStructure) -> np.ndarray:
    """(nb,) least scaled Jacobian of each straight block over its eight corners."""
    return scaled_corner_jacobians(blocks.vertices[blocks.hexes]).min(axis=1)


def moved_blocks(before: BlockStructure, after: BlockStructure) -> np.ndarray | None:
    """Blocks whose corners moved from ``before`` to ``after`` (the same blocks, one
    placement changed); None where the two structures do not have the same blocks.
    Unchanged sections give bit-identical corners, so any difference counts."""
    if before.hexes.shape != after.hexes.shape:
        return None
    return np.flatnonzero(np.any(before.vertices[before.hexes] != after.vertices[after.hexes], axis=(1, 2)))


def fill_summary(blocks: BlockStructure, subset: np.ndarray, project, distance, intersect_lines=None, refinement=None) -> np.ndarray:
    """``(r, 2)``: per resolution of ``refinement`` (default :data:`~.checks.FILL_CHECKS`) the
    least and the mean scaled Jacobian of the elements of the blocks ``subset``, filled as
    :func:`~.checks.fill_quality` fills them (transfinite, without untangling)."""
    return np.array([(float(sj.min()), float(sj.mean())) for _, sj in filled(blocks, subset, project, distance, intersect_lines, refinement)])


def optimised_summary(blocks: BlockStructure, subset: np.ndarray, project, distance, intersect_lines=None) -> tuple[float, float]:
    """Least and mean scaled Jacobian of the elements of the blocks ``subset`` filled at
    the default chain's resolution (the first of :data:`~.checks.FILL_CHECKS`) and then
    optimised as ``mesh_transfinite`` optimises a mesh (untangling and smoothing below
    :data:`OPTIMISED_UNTANGLE_BELOW` / :data:`OPTIMISED_SMOOTH_BELOW`, the light pass to
    :data:`OPTIMISED_LIGHT_BELOW`, the worst pass and the light pass again). The blocks sharing a corner with ``subset`` are
    filled and optimised with them, so the subset's own faces are free as in the whole mesh;
    only the outer faces of that ring are held (wall nodes slide on the wall). ``(-inf,
    -inf)`` where the subset is empty."""
    from ..optimize import _node_kinds, optimise
    from ..optimize.worst import lift_worst

    subset = np.asarray(subset, np.int64)
    if not len(subset):
        return -np.inf, -np.inf
    ring = np.flatnonzero(np.isin(blocks.hexes, blocks.hexes[subset]).any(axis=1))  # subset and its neighbours
    sm, _ = next(filled(blocks, ring, project, distance, intersect_lines, (FILL_CHECKS[0],)))
    own = np.isin(ring[sm.cell_block], subset)
    h = NORMAL_STEP * float(np.median(blocks.block_radius[subset]))

    def normals(x):  # the signed distance's gradient by central differences
        x = np.asarray(x, float)
        g = np.stack([np.asarray(distance(x + h * e)) - np.asarray(distance(x - h * e)) for e in np.eye(3)], axis=1)
        return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)

    wall = np.asarray(sm.on_wall, bool)
    X, _ = optimise(sm.points, sm.cells, 1, wall=wall, wall_normals=normals, project=project, untangle_below=OPTIMISED_UNTANGLE_BELOW,
                    smooth_below=OPTIMISED_SMOOTH_BELOW, max_fraction=1.0)
    X, _ = optimise(X, sm.cells, 1, wall=wall, wall_normals=normals, project=project, untangle_below=0.0, smooth_below=OPTIMISED_LIGHT_BELOW)
    q = hex8_scaled_jacobian(X, sm.cells)
    if 0 < q.min() < OPTIMISED_SMOOTH_BELOW:  # the worst pass: it sets the run's minimum at poor junction columns
        kind, normal, height = _node_kinds(sm.cells, len(X), wall, project, normals, None, None, None, True)
        if lift_worst(X, sm.cells, OPTIMISED_SMOOTH_BELOW, kind, normal, height, project, normals, sweeps=WORST_SWEEPS, ratio_floor=WORST_RATIO_FLOOR):
            X, _ = optimise(X, sm.cells, 1, wall=wall, wall_normals=normals, project=project, untangle_below=0.0, smooth_below=OPTIMISED_LIGHT_BELOW)
    q = hex8_scaled_jacobian(X, sm.cells[own])
    return float(q.min()), float(q.mean())


def shortfall(sj: np.ndarray, floor: float) -> float:
    """Summed shortfall of the blocks' least corner scaled Jacobians ``sj`` below ``floor``."""
    return float(np.maximum(floor - np.asarray(sj), 0.0).sum())


class _PoorBlocks:
    """Mixed into :class:`~vmesh.geometry.blocks.builder._Builder`: the step that treats
    valid but poor blocks as the fix loop treats invalid ones."""

    def lift_poor_blocks(self, blocks: BlockStructure) -> BlockStructure:
        """Repair blocks whose least corner scaled Jacobian is below
        ``repair.poor_block_sj`` with :meth:`~.repair._Repair.fix`, one skeleton segment at
        a time, worst first.

        Each round takes the poor blocks of the segment that holds the worst poor block not
        yet tried and repairs them as the fix loop repairs invalid blocks (all poor blocks
        at once move every junction at once and fold others: s0 g0006 given). The round is
        kept only where every block stays valid, the least block scaled Jacobian over the
        whole structure does not fall, and the summed shortfall below the floor falls;
        else the state goes back and that segment is not tried again. At most
        ``POOR_ROUNDS`` rounds (one assembly per repair tried, two repairs at most). A repair
        whose placement cannot be built (a section finds no wall) is refused like one that
        does not help: the rounds kept before it stay. Returns the kept blocks (``blocks``
        where no round was kept)."""
        floor = self.opt.repair.poor_block_sj
        sj = block_scaled_jacobians(blocks)
        start, kept, refused = float(sj.min()), 0, set()
        for _ in range(POOR_ROUNDS):
            where = [tuple(w) for w in self.built.block_where.tolist()]
            poor = [b for b in np.flatnonzero(sj < floor).tolist() if where[b] not in refused]
            if not poor or self.work.spent:
                break
            key = where[min(poor, key=lambda b: sj[b])]
            group = np.array([b for b in poor if where[b] == key], np.int64)
            got = None
            for repair in (self._closer_to_junction, self._fix_group):
                if self.work.spent:
                    break
                saved = self._saved_state()
                said = len(self.fixes)
                try:
                    trial = self.assemble() if repair(group) else None
                except MeshingError:  # a placement that cannot be built: refused, the kept rounds stay
                    trial = None
                new = block_scaled_jacobians(trial) if trial is not None else None
                judged = None
                if trial is None or self.built.corners.min() <= 0:
                    refuse = True
                elif self.opt.repair.poor_block_optimised:  # the moved blocks' optimised fill
                    judged = self._optimised_judgement(blocks, trial)
                    refuse = not judged["kept"]
                else:
                    refuse = new.min() < sj.min() - 1e-9 or shortfall(new, floor) > shortfall(sj, floor) * (1.0 - POOR_PROGRESS)
                if TRIAL_LOG is not None:
                    self._log_trial(key, repair, blocks, trial, sj, new, floor, not refuse, judged)
                if refuse:
                    self._restore_state(saved)
                    continue
                del self.fixes[said:]  # one note for the step, below
                got = trial, new
                break
            if got is None:
                refused.add(key)
                continue
            blocks, sj = got
            kept += 1
        if kept:
            self.fixes.append(f"lifted poor blocks (least corner scaled Jacobian below {floor:g}) with {kept} round(s) of the "
                              f"invalid-block repairs: least block {start:.3f} -> {float(sj.min()):.3f}, "
                              f"{int((sj < floor).sum())} block(s) left below")
            blocks.info.update(self.built.info)
        return blocks

    def _fix_group(self, group: np.ndarray) -> bool:
        """:meth:`~.repair._Repair.fix` of the poor blocks ``group``, as if they were invalid."""
        return self.fix(group, self.built.corners)

    def _optimised_judgement(self, before: BlockStructure, after: BlockStructure) -> dict:
        """Judge a lift round by the optimised fill (:func:`optimised_summary`) of the blocks
        it moved: kept where their least element rises by :data:`OPTIMISED_GAIN` and their
        mean does not fall. The raw fill and the corners predict the run's minimum poorly at
        junctions (docs/optimiser.md, h25/minima): the optimiser opens the raw folds, and what
        it cannot open is what the run keeps. Returns ``{"moved", "before", "after", "kept"}``."""
        moved = moved_blocks(before, after)
        if moved is None or not len(moved):
            return {"moved": None if moved is None else 0, "kept": False}
        args = (self.project, self.sdf, self.intersect_lines)
        was, now = optimised_summary(before, moved, *args), optimised_summary(after, moved, *args)
        kept = now[0] >= was[0] + OPTIMISED_GAIN and now[1] >= was[1]
        return {"moved": int(len(moved)), "before": [round(v, 4) for v in was], "after": [round(v, 4) for v in now], "kept": bool(kept)}

    def _log_trial(self, key, repair, blocks, trial, sj, new, floor, kept, judged=None) -> None:
        """Append one trial's record to :data:`TRIAL_LOG` (see there); ``judged``: the
        optimised judge's record (:meth:`_optimised_judgement`), where it judged."""
        row = {"segment": [int(k) for k in key], "nodes": [int(n) for n in self.topo.branches[key[0]].nodes[key[1]:key[1] + 2]],
               "repair": repair.__name__, "kept": bool(kept), "built": trial is not None, "optimised": judged,
               "least_block": [float(sj.min()), None if new is None else float(new.min())],
               "shortfall": [shortfall(sj, floor), None if new is None else shortfall(new, floor)]}
        fillable = trial is not None and self.project is not None and self.built.corners.min() > 0  # a fill needs the projector
        moved = moved_blocks(blocks, trial) if fillable else None
        if moved is not None and len(moved):
            row["moved"] = int(len(moved))
            row["fill_before"] = fill_summary(blocks, moved, self.project, self.sdf, self.intersect_lines).round(4).tolist()
            row["fill_after"] = fill_summary(trial, moved, self.project, self.sdf, self.intersect_lines).round(4).tolist()
        TRIAL_LOG.append(row)

    def _closer_to_junction(self, group: np.ndarray) -> bool:
        """Give back half a radius of the extra margin the fix loop gave the junction ends
        whose first segment holds blocks of ``group``; False where none has any.

        The fix loop only moves a junction end's sections away (up to 2 radii), for blocks
        that were invalid then; once other fixes made them valid, the first block column
        can stay far longer than the branch is wide and meet the half-section at a few
        degrees (s1 g0008 extracted: a column 11.2 long at radius 1.9, its junction-side
        corners 0.09-0.21)."""
        changed = False
        for bi, side in self._junction_ends(group):
            br = self.topo.branches[bi]
            if br.margin[side] >= 0.5 - 1e-9:
                br.margin[side] -= 0.5
                changed = True
        if changed:
            self.fixes.append("moved the first cross-sections of poor junction blocks back towards their junction")
            self._apply_clearance()
        return changed
