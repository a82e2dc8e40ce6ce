"""Cross-sections added where the builder's boundary-layer blocks would fold on the wall.

A boundary-layer block whose wall face, projected onto the wall, folds the layer
(:func:`~.checks.projected_wall_quality` at most 0) mostly sits where the wall dips
*between* two cross-sections (along the skeleton, docs/optimiser.md h16/dents): the
block's straight wall face runs outside the vessel there, and thickening the layer (the
builder's other remedy) cannot reach a dip as deep as layer and ring together. A section
in the middle of the block's skeleton segment follows the wall there instead.

:func:`add_dent_sections` halves the segments of the flagged blocks and builds the whole
structure again on that skeleton. The projected quality alone does not say whether the
mesh gets better (on seed 0 g0007 extracted it fell while the fill's folds halved), so the
judge is the fill (:func:`~.checks.fill_quality`, both resolutions, no untangling): only
the halvings whose own segment's blocks fold in the fill and fill better are kept (building once more with
those alone where some did not), and the result is taken only where the blocks of the
halved segments and of the segments next to them fill better together. Each round is at
most two builds and four fills of that stretch; ``dent_sections`` bounds the rounds.
"""

from __future__ import annotations

import numpy as np

from ...blocks import BlockStructure
from ...errors import MeshingError
from ...skeleton import Skeleton
from .checks import fill_score, projected_wall_quality

#: a segment shorter than this many radii (mean of its ends) is not halved: its halves
#: would give blocks much shorter than wide
MIN_SEGMENT_RADII = 0.8


def add_dent_sections(blocks: BlockStructure, build, fill, distance, project, rounds: int, warn=None) -> BlockStructure:
    """``blocks`` with a cross-section added in the middle of each skeleton segment whose
    boundary-layer blocks fold once projected onto the wall, where that helps.

    Parameters
    ----------
    blocks : BlockStructure
        A valid structure; ``info["skeleton"]`` is the skeleton it was built on.
    build : callable
        ``build(skeleton) -> (BlockStructure, warnings)``: the whole build on another
        skeleton (without this step); raises :class:`MeshingError` where it fails. A
        structure it marks ``info["relabelled"]`` (another build's, renumbered:
        ``builder._Rebuilds``) is only judged; the one kept is ``build.exact(skeleton)``'s.
    fill : callable
        ``fill(blocks, subset) -> (k,)`` each block's :func:`~.checks.fill_quality`.
    distance, project : callable
        The builder's signed distance (positive inside) and wall projector.
    rounds : int
        Most rounds of halving (0: ``blocks`` as given).
    warn : callable, optional
        Gets the kept build's warnings and a note of what was added.

    Returns
    -------
    BlockStructure
        ``blocks``, or the structure built on the skeleton with the kept halvings (its
        ``info["skeleton"]``), with a note in ``info["fixes"]``.
    """
    kept_warnings, added = None, 0
    for _ in range(rounds):
        sk = blocks.info.get("skeleton")
        quality = projected_wall_quality(blocks, project)
        split = _flagged_segments(blocks, quality, sk, distance)
        if len(split) == 0:
            break
        trial = _try(build, sk, split)
        if trial is None:
            break
        before = _Stretch(blocks, sk, split, fill)
        after = before.scores(trial[0], split, fill)
        # where the fill already holds, a section only moves what works (s0 g0017 extracted)
        better = split[(after > before.per_segment + 1e-9) & (before.per_segment < 0)]
        if 0 < len(better) < len(split):
            before, trial, split = _Stretch(blocks, sk, better, fill), _try(build, sk, better), better
        if len(better) == 0 or trial is None or before.scores(trial[0], split, fill, whole=True) <= before.whole + 1e-9:
            break
        if trial[0].info.get("relabelled"):  # judged on a relabelled copy (builder._Rebuilds): keep the build itself
            judged, trial = trial[0], _try(getattr(build, "exact", build), sk, split)
            if trial is None:
                break
            # a build may hang on its numbering: one that differs from the copy is judged itself
            if not _same_blocks(judged, trial[0]) and before.scores(trial[0], split, fill, whole=True) <= before.whole + 1e-9:
                break
        blocks, kept_warnings = trial
        added += len(split)
    if kept_warnings is None:
        return blocks
    quality = projected_wall_quality(blocks, project)
    note = (f"added {added} cross-section(s) halfway along skeleton segments whose boundary-layer blocks folded once projected onto the wall "
            f"and filled better with them (now {int(np.sum(quality <= 0))} such block(s), least projected quality {quality.min():.3f})")
    blocks.info["fixes"].append(note)
    blocks.info["dent_sections"] = added
    for msg in kept_warnings + [note]:
        if warn:
            warn(msg)
    return blocks


class _Stretch:
    """The fill of the blocks along the segments ``split`` of ``sk`` and the segments next to
    them (sharing a node), before halving: per split segment and over the whole stretch
    (:func:`~.checks.fill_score`)."""

    def __init__(self, blocks: BlockStructure, sk: Skeleton, split: np.ndarray, fill):
        nodes = np.unique(sk.edges[split])
        self.n_edges = sk.n_edges
        self.segments = np.flatnonzero(np.isin(sk.edges, nodes).any(axis=1))
        subset = np.flatnonzero(np.isin(blocks.block_segment, self.segments))
        q = fill(blocks, subset)
        seg = blocks.block_segment[subset]
        self.per_segment = np.array([fill_score(q[seg == s]) for s in split.tolist()])
        self.whole = fill_score(q)

    def scores(self, trial: BlockStructure, split: np.ndarray, fill, whole: bool = False):
        """The same in ``trial``, built with ``split`` halved (:func:`halve_segments`' ids):
        per split segment over both halves, or (``whole``) over the stretch."""
        halves = self.n_edges + np.arange(len(split))
        subset = np.flatnonzero(np.isin(trial.block_segment, np.r_[self.segments, halves]))
        q = fill(trial, subset)
        seg = trial.block_segment[subset]
        if whole:
            return fill_score(q)
        return np.array([fill_score(q[(seg == s) | (seg == h)]) for s, h in zip(split.tolist(), halves.tolist())])


def _flagged_segments(blocks: BlockStructure, quality: np.ndarray, sk: Skeleton | None, distance) -> np.ndarray:
    """Skeleton segments (ids of ``sk``'s edges) of the blocks that fold on the wall, long
    enough to halve (:data:`MIN_SEGMENT_RADII`) and with their middle inside the vessel."""
    if sk is None:
        return np.zeros(0, np.int64)
    seg = np.unique(blocks.block_segment[(quality <= 0) & (blocks.block_segment >= 0)])
    if len(seg) == 0:
        return seg
    a, b = sk.edges[seg, 0], sk.edges[seg, 1]
    length = np.linalg.norm(sk.points[b] - sk.points[a], axis=1)
    mid = 0.5 * (sk.points[a] + sk.points[b])
    ok = (length >= MIN_SEGMENT_RADII * 0.5 * (sk.radii[a] + sk.radii[b])) & (np.asarray(distance(mid)) > 0)
    return seg[ok]


def halve_segments(sk: Skeleton, split: np.ndarray) -> Skeleton:
    """``sk`` with a node in the middle of each segment of ``split``: segment ``e`` keeps
    its id for its first half, the second halves follow the old segments in ``split``'s
    order. The new node's radius is the mean of its ends', its tags those both ends share."""
    split = np.asarray(split, np.int64)
    a, b = sk.edges[split, 0], sk.edges[split, 1]
    new = sk.n_nodes + np.arange(len(split))
    edges = sk.edges.copy()
    edges[split, 1] = new
    node_tags = list(sk.node_tags) + [tuple(t for t in sk.node_tags[i] if t in sk.node_tags[j]) for i, j in zip(a.tolist(), b.tolist())]
    return Skeleton(np.r_[sk.points, 0.5 * (sk.points[a] + sk.points[b])], np.r_[sk.radii, 0.5 * (sk.radii[a] + sk.radii[b])],
                    np.r_[edges, np.c_[new, b]], node_tags, list(sk.edge_tags) + [sk.edge_tags[e] for e in split.tolist()], sk.name)


def _same_blocks(a: BlockStructure, b: BlockStructure) -> bool:
    """Whether two structures have the same blocks (corner points, in any block order)."""
    if a.hexes.shape != b.hexes.shape:
        return False
    pa, pb = a.vertices[a.hexes].reshape(len(a.hexes), -1), b.vertices[b.hexes].reshape(len(b.hexes), -1)
    return bool(np.array_equal(pa[np.lexsort(pa.T[::-1])], pb[np.lexsort(pb.T[::-1])]))


def _try(build, sk: Skeleton, split: np.ndarray):
    """(blocks, warnings) of the build on ``sk`` with ``split`` halved, or None where it
    fails or changes the skeleton further (junctions split or merged: the segment ids no
    longer match)."""
    halved = halve_segments(sk, split)
    try:
        out, heard = build(halved)
    except MeshingError:
        return None
    built_on = out.info.get("skeleton")
    if built_on is None or built_on.n_edges != halved.n_edges:
        return None
    return out, heard
