"""A junction end's first column of blocks split where its wall dips (the crotch's saddle).

The first segment of a branch at a junction runs from the junction's folded section (two
half-sections, whose vertices beside the node stand at arc 0-1 along the branch) to the
branch's first section (5-13 radii further at an acute pair). Its wall faces are straight
between the two, and where the wall dips in between (the saddle beside the crotch), by
about the boundary layer's thickness, the layer's straight inner face runs outside the wall
and the transfinite fill folds there (docs/junctions.md, h17-h19/crotch). No section
normal to the branch can stand at the dip (it lies below the half-sections' reach along
the branch); this step adds a section of the junction's own column instead: every block of
the segment is split in two at the fraction ``t`` of its along edges where the straight
wall faces dip deepest, and the new section is scaled ray by ray about its centre so that
its wall vertices lie on the wall (:func:`saddle_section`): it follows the saddle, and no
straight face spans the dip. Where a half would not be valid, the section takes half the
scaling of its inner vertices, then moves halfway towards the column's middle; of the
valid tries the one whose column fills best is taken, and only where the column fills
better than unsplit (:func:`column_fill_score`; h21/crotch: s0 g0002 given's split section
reached a sibling's wall through the junction and folded its column), the column filled
with the blocks that share a vertex with it (h22/crotch: a split moves its neighbours' fill
too). The halves are split again the same way (three rounds at most).
"""

from __future__ import annotations

import numpy as np

from ...blocks import FACE_INTERIOR, BlockStructure, hex_corner_jacobians
from .. import cross_sections as cs
from .options import JUNCTION

#: fractions of the first segment's along edges where the dip is looked for
DIP_SAMPLES = np.arange(1, 16) / 16.0


def column_ends(columns: tuple, nq: int) -> list:
    """Per junction end ``(junction-side ids, other ids, block rows)`` of its first segment,
    in template vertex order, from an assembly's ``columns`` (per branch: section ids, first
    block row, end kinds); a branch with one segment between two junctions once."""
    out = []
    for ids, offset, kinds in zip(*columns):
        K = len(ids)
        for side in (0, 1):
            if kinds[side] != JUNCTION or (side == 1 and K == 2 and kinds[0] == JUNCTION):
                continue
            a, b, kseg = (ids[0], ids[1], 0) if side == 0 else (ids[K - 1], ids[K - 2], K - 2)
            out.append((a, b, offset + kseg * nq + np.arange(nq)))
    return out


def dip_fraction(template, A: np.ndarray, B: np.ndarray, sdf) -> tuple[float, float]:
    """Where along the segment (fraction of its along edges from the junction's side) its
    straight wall faces lie deepest outside the wall, over the layer's local thickness, and
    that ratio (the wall edges and the wall faces' mid-lines sampled at :data:`DIP_SAMPLES`)."""
    t = DIP_SAMPLES[:, None, None]
    outer, ring = template.outer, template.ring
    nxt = np.roll(np.arange(len(outer)), -1)
    W = (1 - t) * A[outer][None] + t * B[outer][None]  # (s, n, 3)
    R = (1 - t) * A[ring][None] + t * B[ring][None]
    P = np.concatenate([W, 0.5 * (W + W[:, nxt])], axis=1)
    thick = np.linalg.norm(W - R, axis=2)
    thick = np.concatenate([thick, 0.5 * (thick + thick[:, nxt])], axis=1)
    depth = -np.asarray(sdf(P.reshape(-1, 3)), float).reshape(thick.shape)
    ratio = (depth / np.maximum(thick, 1e-300)).max(axis=1)
    k = int(np.argmax(ratio))
    return float(DIP_SAMPLES[k]), float(ratio[k])


def saddle_section(template, A: np.ndarray, B: np.ndarray, tau: float, cast, follow: float = 1.0) -> np.ndarray:
    """Vertices (nv, 3) of the section at fraction ``tau`` between ``A`` and ``B`` that
    follows the wall: each loop ray's wall vertex moved along the ray from the section's
    centre (the mean of its core vertices) to where it meets the wall (``cast``: origins,
    unit directions, scales -> distances; no wall found, or one further from the centre than
    both end sections' wall vertices on that ray from theirs: not moved), every other vertex
    scaled about the centre as its angle's ray (interpolated round the template's loop;
    ``follow`` < 1 takes that part of the scaling), so the section keeps its shape and its
    layer's share and shrinks into the dip."""
    M = (1 - tau) * A + tau * B
    outer, core = template.outer, template.kind == cs.VERTEX_CORE
    centre = M[core].mean(axis=0)
    arm = M[outer] - centre
    length = np.linalg.norm(arm, axis=1)
    hit = np.asarray(cast(np.repeat(centre[None], len(outer), 0), arm / length[:, None], length), float)
    # a wall met further out than either end section's own arm on that ray is not this
    # column's (the ray left through the junction into a sibling's lumen: s0 g0002 given)
    reach = np.maximum(np.linalg.norm(A[outer] - A[core].mean(axis=0), axis=1), np.linalg.norm(B[outer] - B[core].mean(axis=0), axis=1))
    scale = np.where(np.isfinite(hit) & (hit <= reach), hit / length, 1.0)
    phi = np.mod(np.arctan2(template.xy[:, 1], template.xy[:, 0]), 2 * np.pi)
    s = 1.0 + follow * (np.interp(phi, template.loop_angle, scale, period=2 * np.pi) - 1.0)
    out = centre + s[:, None] * (M - centre)
    out[outer] = centre + scale[:, None] * arm
    return out


def split_column(blocks: BlockStructure, rows: np.ndarray, A_ids: np.ndarray, B_ids: np.ndarray, M: np.ndarray):
    """The blocks ``rows`` (one segment's column, along axis k) split at the new section
    ``M`` (template order, as ``A_ids`` / ``B_ids``): (first halves, second halves,
    new vertices), the first halves taking the rows' places; ``None`` where a half is not valid."""
    nv = len(blocks.vertices)
    new_id = np.full(nv, -1, np.int64)
    new_id[A_ids] = nv + np.arange(len(A_ids))
    new_id[B_ids] = nv + np.arange(len(B_ids))
    H = blocks.hexes[rows]
    mid = new_id[H[:, :4]]
    if np.any(mid < 0) or np.any(new_id[H[:, 4:]] != mid):
        return None
    first, second = np.c_[H[:, :4], mid], np.c_[mid, H[:, 4:]]
    V = np.vstack([blocks.vertices, M])
    if np.any(hex_corner_jacobians(V[np.vstack([first, second])]) <= 0):
        return None
    return first, second, M


def column_fill_score(blocks: BlockStructure, rows: np.ndarray, fill) -> float:
    """One number for how the blocks ``rows`` (a column) fill (``fill(blocks, rows)``: per
    resolution the filled mesh and its elements' scaled Jacobians, :func:`~.checks.filled`):
    the least scaled Jacobian where no element inverts, else minus, summed over the
    resolutions, the share of the column's elements inverted and their mean depth below 0
    (fewer and shallower folds score higher; any fold below every valid fill). Per element
    of the column, not per block, so that a column split in more blocks weighs the same."""
    least, folded = 1.0, 0.0
    for _, sj in fill(blocks, rows):
        least = min(least, float(sj.min(initial=1.0)))
        folded -= float(np.mean(sj <= 0) + np.mean(np.maximum(-sj, 0.0))) if len(sj) else 0.0
    return folded if folded < 0 else least


def neighbour_blocks(blocks: BlockStructure, rows: np.ndarray) -> np.ndarray:
    """The blocks, other than ``rows``, that share a vertex with them."""
    touching = np.isin(blocks.hexes, np.unique(blocks.hexes[rows])).any(axis=1)
    touching[rows] = False
    return np.flatnonzero(touching)


def split_saddle_columns(blocks: BlockStructure, template, ends: list, sdf, cast, ratio: float, fill=None, rounds: int = 3) -> tuple[BlockStructure, list]:
    """``blocks`` with every junction end's first column (:func:`column_ends`) whose wall
    dips ``ratio`` or more of the layer (:func:`dip_fraction`) split at the dip
    (:func:`saddle_section`) where both halves are valid and, given ``fill`` (see
    :func:`column_fill_score`), where the column fills better split than not; and the
    halves split again the same way (``rounds`` in all); and the notes of the splits made."""
    notes = []
    for _ in range(rounds):
        V = blocks.vertices
        splits = []
        for A_ids, B_ids, rows in ends:
            tau, dip = dip_fraction(template, V[A_ids], V[B_ids], sdf)
            if dip < ratio:
                continue
            got, t = _best_split(blocks, template, (A_ids, B_ids, rows), tau, cast, fill)
            if got is not None:
                splits.append(((A_ids, B_ids, rows), got))
                notes.append(f"split the first blocks at node {int(blocks.block_node[rows[0]])} (segment {int(blocks.block_segment[rows[0]])}) "
                             f"at {t:.2f} of their length (wall dip {dip:.2f} layers)")
        if not splits:
            break
        blocks, halves = _with_splits(blocks, template, splits)
        ends = [h for pair in halves for h in pair]
    return blocks, notes


def _best_split(blocks: BlockStructure, template, end: tuple, tau: float, cast, fill):
    """The split of the column ``end`` (:func:`split_column`'s result) and its fraction: at
    the dip ``tau``, then halfway to the middle, each with its inner vertices' full and half
    scaling. Without ``fill`` the first whose halves are valid; with it the one whose column
    and its neighbours (:func:`neighbour_blocks`) fill best (:func:`column_fill_score`), and
    none where that is not better than their fill unsplit (a split that folds the fill more
    than it was must not stand)."""
    A_ids, B_ids, rows = end
    V = blocks.vertices
    best, best_t = None, None
    # the column with the blocks that share a vertex with it: a split moves their fill too
    # (the along edges' bulges are averaged over the blocks that share them,
    # transfinite_curves._smooth_bulges), which the column filled alone does not see
    # (s0 g0002 given: its least sits in an unsplit neighbour column at the same junction)
    judged = np.r_[rows, neighbour_blocks(blocks, rows)] if fill is not None else rows
    best_score = column_fill_score(blocks, judged, fill) if fill is not None else -np.inf
    halves = np.r_[judged, len(blocks.hexes) + np.arange(len(rows))]
    # the dip itself, then halfway to the middle (the same where the dip is the middle)
    for t, follow in dict.fromkeys(((tau, 1.0), (tau, 0.5), (0.5 * (tau + 0.5), 1.0), (0.5 * (tau + 0.5), 0.5))):
        got = split_column(blocks, rows, A_ids, B_ids, saddle_section(template, V[A_ids], V[B_ids], t, cast, follow))
        if got is None:
            continue
        if fill is None:
            return got, t
        score = column_fill_score(_with_splits(blocks, template, [(end, got)])[0], halves, fill)
        if score > best_score + 1e-9:  # strictly better: a tie with the unsplit column keeps it unsplit
            best, best_t, best_score = got, t, score
    return best, best_t


def _with_splits(blocks: BlockStructure, template, splits: list):
    """``blocks`` with the columns of ``splits`` (``(end, (first, second, M, ...))``) split:
    the new structure and per split its two halves' columns ``(A, M, rows), (M, B, rows)``
    (each with the block rows it now lies in, whichever end of the column is ``A``)."""
    V = blocks.vertices
    hexes, new_vertices, added, halves = blocks.hexes.copy(), [], [], []
    fb = blocks.face_boundary
    n_new, n_blocks = len(V), len(hexes)
    for (A_ids, B_ids, rows), got in splits:
        first, second, M = got[0].copy(), got[1].copy(), got[2]
        shift = n_new - len(V)
        first[:, 4:] += shift
        second[:, :4] += shift
        hexes[rows] = first
        new_vertices.append(M)
        added.append((rows, second))
        mid_ids, new_rows = n_new + np.arange(len(M)), n_blocks + np.arange(len(rows))
        # the first halves start on the rows' first faces: B's at a branch's far end (side 1)
        a_rows, b_rows = (new_rows, rows) if np.isin(got[0][:, :4], B_ids).all() else (rows, new_rows)
        halves.append(((A_ids, mid_ids, a_rows), (mid_ids, B_ids, b_rows)))
        n_new += len(M)
        n_blocks += len(rows)
    rows = np.concatenate([r for r, _ in added])
    f_first = fb.copy()
    f_first[rows, 5] = FACE_INTERIOR
    f_second = fb[rows].copy()
    f_second[:, 4] = FACE_INTERIOR
    on = np.concatenate([blocks.vertex_on_surface] + [np.isin(np.arange(len(M)), template.outer) for M in new_vertices])
    out = BlockStructure(
        vertices=np.vstack([V] + new_vertices),
        hexes=np.vstack([hexes] + [s for _, s in added]),
        vertex_on_surface=on,
        face_boundary=np.vstack([f_first, f_second]),
        axis_kind=np.vstack([blocks.axis_kind, blocks.axis_kind[rows]]),
        block_radius=np.r_[blocks.block_radius, blocks.block_radius[rows]],
        block_node=np.r_[blocks.block_node, blocks.block_node[rows]],
        block_segment=np.r_[blocks.block_segment, blocks.block_segment[rows]],
        block_layer=np.r_[blocks.block_layer, blocks.block_layer[rows]],
        block_tags=list(blocks.block_tags) + [blocks.block_tags[i] for i in rows.tolist()],
        boundary_names=dict(blocks.boundary_names),
        info=dict(blocks.info),
    )
    return out, halves
