"""Reuse of a chain's geometry prefix (everything up to the signed distance) across runs.

A batch meshes the same surface many times with different meshing parameters; the
steps up to ``build_sdf`` (repair, capping, decimation, the SDF's AABB trees) give the
same result every time. :class:`PrefixCache` keeps the context layers those steps
wrote, keyed by the steps' resolved parameters and a fingerprint of the input layers
they read, and :meth:`vmesh.FilterChain.run` consults it through ``Context.cache``:

>>> from vmesh.cache import PrefixCache
>>> cache = PrefixCache(max_entries=2)
>>> ctx = chain.run(surface="vessel.stl", out_dir="a", context=Context(cache=cache))   # doctest: +SKIP
>>> ctx = chain.with_overrides({"mesh_transfinite.first_layer": 0.01}).run(
...     surface="vessel.stl", out_dir="b", context=Context(cache=cache))              # doctest: +SKIP

The second run restores the first four steps instead of running them (their report
entries say ``"cached": true``). Rows whose surface-affecting parameters differ (e.g.
``scale_radius.scale``) get different keys and build their own signed distance.

The cached signed distance is shared, not copied: filters only query it. Every other
layer is deep-copied in and out, so a later filter that changes a layer in place
cannot alter the cache.
"""

from __future__ import annotations

import copy
import hashlib
import json
import threading
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

#: Layers that are shared between runs rather than copied (large, read-only).
SHARED_LAYERS = ("sdf",)
#: Categories of filters that write files: a prefix holding one is never cached (its
#: files would be missing from later runs' outputs).
_FILE_CATEGORIES = ("export",)


def fingerprint(obj) -> str | None:
    """Content hash of a surface or skeleton layer; ``None`` for other objects.

    The hash covers the arrays' bytes, so the same file read twice (or under two
    paths) gives the same fingerprint, and any change to it a different one.
    """
    from .skeleton import Skeleton
    from .surface import SurfaceMesh

    h = hashlib.blake2b(digest_size=16)
    if isinstance(obj, SurfaceMesh):
        h.update(b"surface")
        parts = [obj.vertices, obj.faces] + [np.asarray(obj.face_data[k]) for k in sorted(obj.face_data)]
        h.update(repr(sorted(obj.face_data)).encode())
    elif isinstance(obj, Skeleton):
        h.update(b"skeleton")
        parts = [obj.points, obj.radii, obj.edges]
        h.update(repr((obj.node_tags, obj.edge_tags)).encode())
    else:
        return None
    for a in parts:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _copy(value):
    try:
        return copy.deepcopy(value)
    except Exception:  # an object that cannot be copied is shared (and must not be changed)
        return value


@dataclass
class _Entry:
    layers: dict
    steps: list
    sections: dict
    warnings: list


@dataclass
class PrefixPlan:
    """What one run does with the cache: ``skip`` steps restored from it, and the
    step count after which :meth:`store` saves the prefix (``0``: never)."""

    cache: "PrefixCache"
    key: str | None = None
    skip: int = 0
    store_after: int = 0
    hit: bool = False
    _sections_before: dict = field(default_factory=dict)
    _warnings_before: int = 0

    def store(self, ctx) -> None:
        """Save the layers and report entries written by the first ``store_after`` steps."""
        if self.key is None or not self.store_after:
            return
        writes = self.cache.prefix_writes(ctx.report.steps[-self.store_after :])
        before = self._sections_before
        sections = {k: v for k, v in ctx.report.sections.items() if before.get(k, _MISSING) is not v}
        entry = _Entry(
            layers={layer: (getattr(ctx, layer) if layer in SHARED_LAYERS else _copy(getattr(ctx, layer))) for layer in writes},
            steps=[replace(s, counts=dict(s.counts), warnings=list(s.warnings)) for s in ctx.report.steps[-self.store_after :]],
            sections=_copy(sections),
            warnings=list(ctx.report.warnings[self._warnings_before :]),
        )
        self.cache._put(self.key, entry)


_MISSING = object()


class PrefixCache:
    """A small LRU cache of chain prefixes (the steps through the first that writes the
    signed distance), safe to share between the threads of one process.

    Parameters
    ----------
    max_entries : int
        Prefixes kept (least recently used dropped first). Each holds a signed
        distance (AABB trees of the fine and/or coarse surface: roughly 0.5 KB per
        triangle) plus the preprocessed surfaces.
    """

    def __init__(self, max_entries: int = 2):
        self.max_entries = max(int(max_entries), 0)
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    @staticmethod
    def prefix_length(steps) -> int:
        """Number of leading steps that can be cached: through the first step writing
        ``sdf``; 0 when there is none or an earlier step writes files."""
        from .registry import get_filter

        for i, step in enumerate(steps):
            f = get_filter(step.filter)
            if f.category in _FILE_CATEGORIES:
                return 0
            if "sdf" in f.writes:
                return i + 1
        return 0

    @staticmethod
    def prefix_writes(steps) -> list[str]:
        from .registry import get_filter

        out: list[str] = []
        for s in steps:
            out += [layer for layer in get_filter(s.filter).writes if layer not in out]
        return out

    def key(self, ctx, steps) -> str | None:
        """Key of a prefix: its resolved steps plus fingerprints of the layers it reads
        that the context already holds; ``None`` when an input cannot be fingerprinted."""
        from .registry import get_filter

        reads = []
        for s in steps:
            f = get_filter(s.filter)
            reads += [layer for layer in (*f.reads, *f.optional_reads) if layer not in reads]
        prints = {}
        for layer in sorted(reads):
            if ctx.has(layer):
                fp = fingerprint(getattr(ctx, layer))
                if fp is None:
                    return None
                prints[layer] = fp
        text = json.dumps({"steps": [[s.filter, s.params] for s in steps], "inputs": prints}, sort_keys=True, default=str)
        return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()

    def plan(self, ctx, steps) -> PrefixPlan:
        """Restore a cached prefix into ``ctx`` if there is one; say what the run skips
        and when it should store the prefix."""
        n = self.prefix_length(steps)
        if not n or not self.max_entries or ctx.has("sdf"):
            return PrefixPlan(self)
        key = self.key(ctx, steps[:n])
        if key is None:
            return PrefixPlan(self)
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
                self.hits += 1
            else:
                self.misses += 1
        if entry is None:
            return PrefixPlan(self, key=key, store_after=n, _sections_before=dict(ctx.report.sections), _warnings_before=len(ctx.report.warnings))
        for layer, value in entry.layers.items():
            setattr(ctx, layer, value if layer in SHARED_LAYERS else _copy(value))
        ctx.report.steps += [replace(s, seconds=0.0, extra_memory_mb=0.0, cached=True, counts=dict(s.counts), warnings=list(s.warnings)) for s in entry.steps]
        ctx.report.sections.update(_copy(entry.sections))
        ctx.report.warnings += entry.warnings
        return PrefixPlan(self, key=key, skip=n, hit=True)

    def _put(self, key: str, entry: _Entry) -> None:
        with self._lock:
            self._entries[key] = entry
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)
