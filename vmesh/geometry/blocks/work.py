"""Bounded work for the block builder: rays cast once per build, and a budget of assemblies.

Every fix round re-assembles the whole block structure, and every changed skeleton that
:func:`~vmesh.geometry.blocks.builder.build_blocks` tries starts a new builder; both used
to cast every section's rays again, so a tree of thousands of sections that fails at one
junction spent minutes casting the same rays. :class:`RayCache` keeps each ray's result
(rays depend only on their origin, direction, scale and reach, so a section that did not
move is cast once per build), and :class:`WorkBudget` bounds the number of assemblies a
build may do, so that a structure that cannot be made valid fails after a fixed multiple
of one assembly's work instead of after every try.
"""

from __future__ import annotations

import numpy as np

from .. import cross_sections as cs

_FNV_OFFSET = np.uint64(0xCBF29CE484222325)
_FNV_PRIME = np.uint64(0x100000001B3)


def _row_hashes(rows: np.ndarray) -> np.ndarray:
    """(n,) uint64 FNV-1a hash of each row's bytes (one pass per column, not per row)."""
    words = np.ascontiguousarray(rows, np.float64).view(np.uint64)
    h = np.full(len(words), _FNV_OFFSET, np.uint64)
    for c in range(words.shape[1]):
        h = (h ^ words[:, c]) * _FNV_PRIME
    return h


class RayCache:
    """Wall distances of rays already cast (:func:`~vmesh.geometry.cross_sections.cast_rays`),
    keyed by the exact ray.

    Parameters
    ----------
    limit : int
        Most rays kept; beyond it the cache starts again empty (memory stays bounded:
        about 90 bytes a ray).

    Attributes
    ----------
    hits, misses : int
        Rays answered from the cache and rays cast.
    """

    def __init__(self, limit: int = 4_000_000):
        self.limit = int(limit)
        self.hits = self.misses = 0
        self._clear()

    def _clear(self):
        # two sorted levels: the rays cast since the last merge are kept apart until they
        # are an eighth of the rest, so that the many small casts of a build (one junction's
        # half-planes at a time) do not re-sort the whole cache each
        self._levels = [_Level(), _Level()]

    def __len__(self) -> int:
        return sum(len(level.keys) for level in self._levels)

    def cast(self, distance, origins, directions, scale, reach: float = 12.0, intersect_lines=None) -> np.ndarray:
        """:func:`~vmesh.geometry.cross_sections.cast_rays` with the rays cast before
        answered from the cache (bit for bit the same: each ray is cast on its own)."""
        o = np.asarray(origins, float).reshape(-1, 3)
        d = np.asarray(directions, float).reshape(-1, 3)
        n = len(o)
        if n == 0:
            return np.zeros(0)
        rows = np.empty((n, 8))
        rows[:, :3], rows[:, 3:6] = o, d
        rows[:, 6] = np.broadcast_to(np.asarray(scale, float), (n,))
        rows[:, 7] = reach
        h = _row_hashes(rows)
        out = np.full(n, np.nan)
        found = np.zeros(n, bool)
        for level in self._levels:
            level.find(h, rows, out, found)
        miss = np.flatnonzero(~found)
        self.hits += n - len(miss)
        self.misses += len(miss)
        if len(miss):
            out[miss] = cs.cast_rays(distance, o[miss], d[miss], rows[miss, 6], reach=reach, intersect_lines=intersect_lines)
            self._store(h[miss], rows[miss], out[miss])
        return out

    def _store(self, keys, rows, values):
        if len(self) + len(keys) > self.limit:
            self._clear()
        main, recent = self._levels
        recent.add(keys, rows, values)
        if 8 * len(recent.keys) > len(main.keys):
            main.add(recent.keys, recent.rows, recent.values)
            self._levels[1] = _Level()


class _Level:
    """Rays sorted by their hash: ``keys`` (uint64), ``rows`` (origin, direction, scale,
    reach) and ``values`` (the wall distances)."""

    def __init__(self):
        self.keys = np.zeros(0, np.uint64)
        self.rows = np.zeros((0, 8))
        self.values = np.zeros(0)

    def find(self, h, rows, out, found) -> None:
        """Fill ``out`` and set ``found`` where a ray not found yet is here."""
        todo = np.flatnonzero(~found)
        if len(self.keys) == 0 or len(todo) == 0:
            return
        pos = np.minimum(np.searchsorted(self.keys, h[todo]), len(self.keys) - 1)
        hit = (self.keys[pos] == h[todo]) & np.all(self.rows[pos] == rows[todo], axis=1)
        out[todo[hit]] = self.values[pos[hit]]
        found[todo[hit]] = True

    def add(self, keys, rows, values) -> None:
        keys = np.concatenate([self.keys, keys])
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.rows = np.concatenate([self.rows, rows])[order]
        self.values = np.concatenate([self.values, values])[order]


class WorkBudget:
    """Assemblies of the whole block structure one :func:`build_blocks` call may do, over
    all its fix rounds and changed skeletons.

    One assembly costs time in proportion to the tree, so a budget counted in assemblies
    bounds a build by a fixed multiple of the tree's size, however many junctions fail.

    Parameters
    ----------
    assemblies : int
        The budget; ``0`` for none.
    """

    def __init__(self, assemblies: int = 0):
        self.limit = int(assemblies)
        self.used = 0
        self.valid_after = None  # assemblies spent when the blocks were first all valid
        self.rays = RayCache()

    @property
    def spent(self) -> bool:
        """True once the budget is used up."""
        return self.limit > 0 and self.used >= self.limit

    def charge(self) -> None:
        """Count one assembly."""
        self.used += 1

    def stop_note(self) -> str:
        """What the error of a failed build adds when the budget stopped it ("" otherwise)."""
        if not self.spent:
            return ""
        return (f"; stopped after {self.used} assemblies of the block structure (build_block_structure.work_budget "
                f"= {self.limit}: a larger budget lets more fixes and changed skeletons be tried)")

    def summary(self) -> dict:
        """What the build spent: assemblies (``valid_after``: those until every block was valid;
        the rest relieve wall folds, bounded by the options), the budget, rays cast and reused."""
        return {"assemblies": self.used, "valid_after": self.valid_after, "work_budget": self.limit,
                "rays_cast": self.rays.misses, "rays_reused": self.rays.hits}

