"""Cross-sections that cross their neighbour in a bend: the bend's node dropped.

A regular cross-section's rays reach the wall in its plane. Where a skeleton with the
radii of a lumen's thin side turns at every node (one wandering over a flattened lumen's
medial sheet, turning 30-37 degrees at nodes 1-2 radii apart), the section planes cut the
wall obliquely and their rays reach three to four times the node's radius. Two
neighbouring sections tilted by the bend then cross each other within that reach, though
their centres are a radius apart: a plane turned by ``theta``
against its neighbour ``gap`` away crosses it ``gap / tan(theta)`` from the axis, inside
rays of length ``R`` once ``tan(theta) > gap / R``. The fix loop straightens both
planes towards their chords (:meth:`~.repair._Repair.fix`), which turns them by at most
half the bend and leaves them crossing; the blocks between them stay inverted (corner
Jacobians of -30 against +40).

Dropping the sharper bend's node from the skeleton leaves its neighbours, now two
segments apart, turned by the bend against each other over twice the gap: they part. This
runs only where every other try of the build failed (:func:`~.builder._build_blocks`),
so no structure the builder makes without it changes. Opt-in (``bend_drops``, default 0): it
won no run of the corpora; where it builds, the joined segment can leave the bend's outer
wall uncovered and the run fails later (docs/junctions.md h24/realbuild).
"""

from __future__ import annotations

import numpy as np

from ..skeleton.graph import remove_nodes
from .options import JUNCTION

#: A section's straighten weight (towards its chord, steps of ``STRAIGHTEN_STEP`` capped at 1) at and above
#: which the fix loop has none left to give (below 1 so the last step's rounding counts).
#: The fix loop (:mod:`.repair`) and :func:`crossing_bends` share it.
STRAIGHT = 0.99
#: The fix loop's step of a section's straighten weight.
STRAIGHTEN_STEP = 0.34
#: Nodes a branch keeps after its drops: one regular section between its ends (3 nodes, 2
#: segments); a branch with fewer has no bend node to give.
KEPT_BRANCH_NODES = 3


def crossing_bends(builder, bad: np.ndarray) -> list:
    """The skeleton nodes to drop for the invalid blocks ``bad`` of ``builder`` (a
    :class:`~.builder._Builder` whose fix loop gave up): per failing segment between two
    regular sections that are both straightened as far as they go, its interior node where
    the skeleton turns more (the bend whose tilted section crosses its neighbour).

    Parameters
    ----------
    builder : _Builder
        After its fix loop, with ``built.block_where`` and ``topo``.
    bad : (m,) int array
        The invalid blocks.

    Returns
    -------
    list of int
        Skeleton nodes, sorted, each of degree 2; empty where no failing segment is such a
        stuck regular one. A branch gives at most ``K - KEPT_BRANCH_NODES`` of its ``K``
        nodes (the sharpest turns), so it keeps at least one regular section.
    """
    picked = {}  # branch -> {position along it: turn there}
    for bi, k in np.unique(builder.built.block_where[np.asarray(bad)], axis=0).tolist():
        br = builder.topo.branches[bi]
        K = len(br.nodes)
        at_junction = (k == 0 and br.kinds[0] == JUNCTION) or (k + 1 == K - 1 and br.kinds[1] == JUNCTION)
        if at_junction or K <= KEPT_BRANCH_NODES or br.straighten is None or min(br.straighten[k], br.straighten[k + 1]) < STRAIGHT:
            continue
        inner = [kk for kk in (k, k + 1) if 0 < kk < K - 1]
        if inner:
            turn = [_turn(builder.topo.pos[br.nodes[kk - 1: kk + 2]]) for kk in inner]
            best = int(np.argmax(turn))
            picked.setdefault(bi, {})[inner[best]] = turn[best]
    out = []
    for bi, turns in picked.items():
        br = builder.topo.branches[bi]
        sharpest = sorted(turns, key=turns.get, reverse=True)[: len(br.nodes) - KEPT_BRANCH_NODES]
        out += [int(br.nodes[kk]) for kk in sharpest]
    return sorted(out)


def _turn(P: np.ndarray) -> float:
    """The angle (radians) between the two segments of the three points ``P``."""
    a, b = P[1] - P[0], P[2] - P[1]
    return float(np.arccos(np.clip(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-300), -1.0, 1.0)))


def without_bends(skeleton, nodes: list):
    """``skeleton`` with the degree-2 ``nodes`` dropped, their two segments joined."""
    drop = np.zeros(skeleton.n_nodes, bool)
    drop[np.asarray(nodes, np.int64)] = True
    return remove_nodes(skeleton, drop, bridge=True)


def bend_note(nodes: list) -> str:
    """The fix's line in ``info["fixes"]``."""
    return (f"dropped the cross-section(s) at skeleton node(s) {nodes}: in a bend, straightened as far as they go, they still crossed "
            "their neighbours within the reach of their rays (every other try failed)")
