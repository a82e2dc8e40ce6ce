"""Valid blocks that are poor: lift blocks whose own corner scaled Jacobian is low.

The builder's fix loop (:meth:`~.repair._Repair.fix`) makes every block's corner Jacobians
positive and stops there. A straight block whose least corner scaled Jacobian is 0.1 is
valid, but its transfinite fill cannot be better than the block itself: the elements in
it end near that value whatever the optimisers do (docs/optimiser.md, h23/minima: blocks of
0.09-0.25 before the fill, final minima 0.18-0.26 in s1 g0008 extracted, s1 g0010 given,
s0 g0006 given). :meth:`_PoorBlocks.lift_poor_blocks` gives such blocks the same repairs as
invalid ones, round by round, and keeps a round only where the blocks it moved fill better:
their least element higher and the mean of their elements no lower (h25/minima; session 24
judged a round by the blocks' corners, which predict a junction's fill poorly, and lost s0
g0006 given 0.023 of its mean); where nothing helps, the valid structure stays as it was
(the run does not fail on it).
"""

from __future__ import annotations

import numpy as np

from ...blocks import BlockStructure, scaled_corner_jacobians
from ...errors import MeshingError
from .checks import filled

#: Rounds of :meth:`_PoorBlocks.lift_poor_blocks`, one segment each: each is one or two
#: assemblies of the whole structure (one per repair tried: 16 at most, a tenth of the
#: default work budget of 160, so a tree that needed most of it to become valid is not held
#: up by the lift much longer).
POOR_ROUNDS = 8

#: How much the least filled element of the blocks a round moved must rise for the round
#: to count (scaled Jacobian): a gain below it is rounding and untangling noise (the
#: optimisers move an element's scaled Jacobian by more), and the round only spends an
#: assembly.
POOR_GAIN = 1e-3

#: How far (× the structure's bounding-box size) a block corner must move to count a block as
#: moved by a round: unchanged sections give bit-identical corners, so this only absorbs
#: rounding of the frames transported along a branch.
MOVED = 1e-12


def block_scaled_jacobians(blocks: BlockStructure) -> np.ndarray:
    """(nb,) least scaled Jacobian of each straight block over its eight corners."""
    return scaled_corner_jacobians(blocks.vertices[blocks.hexes]).min(axis=1)


def moved_blocks(before: BlockStructure, after: BlockStructure) -> np.ndarray | None:
    """Blocks whose corners moved from ``before`` to ``after`` (the same blocks, one
    placement changed); None where the two structures do not have the same blocks."""
    if before.hexes.shape != after.hexes.shape:
        return None
    a, b = before.vertices[before.hexes], after.vertices[after.hexes]
    size = float(np.ptp(before.vertices, axis=0).max()) or 1.0
    return np.flatnonzero(np.abs(a - b).max(axis=(1, 2)) > MOVED * size)


def fill_summary(blocks: BlockStructure, subset: np.ndarray, project, distance, intersect_lines=None, refinement=None) -> np.ndarray:
    """``(r, 2)``: per resolution of ``refinement`` (default :data:`~.checks.FILL_CHECKS`) the
    least and the mean scaled Jacobian of the elements of the blocks ``subset``, filled as
    :func:`~.checks.fill_quality` fills them (transfinite, without untangling)."""
    return np.array([(float(sj.min()), float(sj.mean())) for _, sj in filled(blocks, subset, project, distance, intersect_lines, refinement)])


def round_lifts(before: np.ndarray, after: np.ndarray, gain: float = POOR_GAIN) -> bool:
    """Whether the :func:`fill_summary` ``after`` a round is better than ``before``: the least
    element over the resolutions higher by ``gain``, and the mean no lower at any resolution."""
    before, after = np.asarray(before, float), np.asarray(after, float)
    return bool(after[:, 0].min() >= before[:, 0].min() + gain and np.all(after[:, 1] >= before[:, 1]))


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
        judged by the fill of the blocks it moved (:func:`fill_summary`, without
        untangling, at each resolution of :data:`~.checks.FILL_CHECKS`): it is kept only
        where every block stays valid, the least filled element of those blocks rises by
        ``POOR_GAIN`` and the mean of their elements does not fall at any resolution (a
        round judged by the blocks' corners alone lengthened first block columns and cost
        s0 g0006 given 0.023 of its mean); else the state goes back and that segment is not
        tried again. At most ``POOR_ROUNDS`` rounds (one assembly per repair tried, two
        repairs at most). A repair whose placement cannot be built (a section finds no
        wall) is refused like one that does not help: the rounds kept before it stay.
        Returns the kept blocks (``blocks`` where no round was kept)."""
        floor = self.opt.repair.poor_block_sj
        sj = block_scaled_jacobians(blocks)
        start, kept, refused = float(sj.min()), 0, set()
        gains = []
        for _ in range(POOR_ROUNDS):
            where = [tuple(w) for w in self.built.block_where.tolist()]
            poor = [b for b in np.flatnonzero(sj < floor).tolist() if where[b] not in refused]
            if not poor or self.work.spent:
                break
            key = where[min(poor, key=lambda b: sj[b])]
            group = np.array([b for b in poor if where[b] == key], np.int64)
            got = None
            for repair in (self._closer_to_junction, lambda g: self.fix(g, self.built.corners)):
                if self.work.spent:
                    break
                saved = self._saved_state()
                said = len(self.fixes)
                try:
                    trial = self.assemble() if repair(group) else None
                except MeshingError:  # a placement that cannot be built: refused, the kept rounds stay
                    trial = None
                judged = self._judge_round(blocks, trial) if trial is not None and self.built.corners.min() > 0 else None
                if judged is None:
                    self._restore_state(saved)
                    continue
                del self.fixes[said:]  # one note for the step, below
                got = trial, block_scaled_jacobians(trial), judged
                break
            if got is None:
                refused.add(key)
                continue
            blocks, sj, judged = got
            gains.append(judged)
            kept += 1
        if kept:
            moved = "; ".join(f"{n} block(s) filled {b[0]:.3f}/{b[1]:.3f} -> {a[0]:.3f}/{a[1]:.3f}" for n, b, a in gains)
            self.fixes.append(f"lifted poor blocks (least corner scaled Jacobian below {floor:g}) with {kept} round(s) of the "
                              f"invalid-block repairs (least/mean filled element of the blocks each moved: {moved}): least block "
                              f"{start:.3f} -> {float(sj.min()):.3f}, {int((sj < floor).sum())} block(s) left below")
            blocks.info.update(self.built.info)
        return blocks

    def _judge_round(self, before: BlockStructure, after: BlockStructure):
        """Whether a lift round from ``before`` to ``after`` (both valid) is kept: the blocks
        it moved (:func:`moved_blocks`), filled, must have a least element higher by
        ``POOR_GAIN`` and a mean no lower, at every resolution (:func:`round_lifts`).
        Returns ``(moved blocks, (least, mean) before, (least, mean) after)`` at the
        default chain's resolution, or None where refused."""
        moved = moved_blocks(before, after)
        if moved is None or len(moved) == 0:
            return None
        old = fill_summary(before, moved, self.project, self.sdf, self.intersect_lines)
        new = fill_summary(after, moved, self.project, self.sdf, self.intersect_lines)
        if not round_lifts(old, new):
            return None
        return len(moved), tuple(old[0]), tuple(new[0])

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
