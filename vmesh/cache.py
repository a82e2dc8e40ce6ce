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

:class:`DiskPrefixCache` keeps the same entries on disk between processes (``vmesh run``
uses it): a rerun on the same surface with other meshing parameters restores the prefix.
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
    #: layer -> the trees built over that surface (:class:`DiskPrefixCache` only)
    trees: dict = field(default_factory=dict)


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
            layers={layer: self.cache._keep_layer(layer, getattr(ctx, layer)) for layer in writes},
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
            reads += [layer for layer in get_filter(s.filter).layers_read(s.params) if layer not in reads]
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
        entry = self._get(key)
        if entry is None:
            return PrefixPlan(self, key=key, store_after=n, _sections_before=dict(ctx.report.sections), _warnings_before=len(ctx.report.warnings))
        self._restore(ctx, entry)
        return PrefixPlan(self, key=key, skip=n, hit=True)

    def _get(self, key: str) -> _Entry | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
                self.hits += 1
            else:
                self.misses += 1
        return entry

    @staticmethod
    def _keep_layer(layer: str, value):
        """What an entry holds of a layer: the object itself (shared layers) or a copy."""
        return value if layer in SHARED_LAYERS else _copy(value)

    def _restore(self, ctx, entry: _Entry, copy_layers: bool = True) -> None:
        """Put an entry's layers and report entries into ``ctx``."""
        for layer, value in entry.layers.items():
            setattr(ctx, layer, value if layer in SHARED_LAYERS or not copy_layers else _copy(value))
        ctx.report.steps += [replace(s, seconds=0.0, cpu_seconds=0.0, extra_memory_mb=0.0, cached=True, counts=dict(s.counts), warnings=list(s.warnings)) for s in entry.steps]
        ctx.report.sections.update(_copy(entry.sections))
        ctx.report.warnings += entry.warnings

    def _put(self, key: str, entry: _Entry) -> None:
        with self._lock:
            self._entries[key] = entry
            self._entries.move_to_end(key)
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)


#: prefixes kept on disk (each holds the surfaces and the signed distance's trees: ~80 MB for
#: the ICA's 150,000 triangles)
DISK_KEEP = 4


class DiskPrefixCache(PrefixCache):
    """The prefix cache kept on disk between processes (``vmesh run``'s default).

    Re-meshing a vessel with other meshing parameters is the common case, and a new process
    repeated repair, capping and the signed distance's trees each time (~1.5 s CPU for the
    ICA's 150,000 triangles, with the decimation already read back from
    :mod:`vmesh.disk_cache`). The entry is the in-memory cache's (layers, step reports,
    report sections, warnings) pickled with the trees already built over its surfaces
    (:func:`vmesh.geometry.projection.cached_trees`), under the prefix's key plus a digest
    of vmesh's sources and the versions of the libraries the prefix calls: an edited module
    or another library version misses, so a hit is what the steps would compute now.

    Files: ``<cache>/prefix/<digest>.pkl`` (:func:`vmesh.disk_cache.store_object`), the newest
    :data:`DISK_KEEP` kept; ``VMESH_DISK_CACHE=0`` turns it off. An unreadable entry only
    means the steps run. A step patched at run time (a test's monkeypatch) is not in the
    key: such a test runs ``vmesh run`` with ``VMESH_DISK_CACHE=0``.
    """

    def __init__(self):
        super().__init__(max_entries=1)

    @staticmethod
    def _digest(key: str) -> str:
        from . import disk_cache

        return disk_cache.key("prefix", key, _sources_digest(), _versions())

    def _get(self, key: str) -> _Entry | None:
        from . import disk_cache

        entry = disk_cache.load_object("prefix", self._digest(key))
        if isinstance(entry, _Entry):
            self.hits += 1
            return entry
        self.misses += 1
        return None

    @staticmethod
    def _keep_layer(layer: str, value):
        return value  # pickled in _put: the copy, with the trees the objects share

    def _restore(self, ctx, entry: _Entry, copy_layers: bool = False) -> None:
        from .geometry.projection import adopt_trees

        super()._restore(ctx, entry, copy_layers=False)  # fresh from disk: nothing else holds them
        for layer, trees in entry.trees.items():
            adopt_trees(getattr(ctx, layer), trees)

    def _put(self, key: str, entry: _Entry) -> None:
        from . import disk_cache
        from .geometry.projection import cached_trees
        from .surface import SurfaceMesh

        if not disk_cache.enabled():
            return
        entry.trees = {layer: cached_trees(v) for layer, v in entry.layers.items() if isinstance(v, SurfaceMesh)}
        try:
            disk_cache.store_object("prefix", self._digest(key), entry, keep=DISK_KEEP)
        finally:
            entry.trees = {}


_DIGEST: list = []


def _sources_digest() -> str:
    """Digest of every module of the vmesh package (computed once per process, ~20 ms)."""
    if not _DIGEST:
        import pathlib

        root = pathlib.Path(__file__).resolve().parent
        h = hashlib.blake2b(digest_size=16)
        for p in sorted(root.rglob("*.py")):
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
        _DIGEST.append(h.hexdigest())
    return _DIGEST[0]


def _versions() -> tuple:
    """Versions of the libraries whose results a prefix holds."""
    import sys
    from importlib.metadata import PackageNotFoundError, version

    out = [sys.version, np.__version__]
    for dist in ("numba", "pymeshlab", "libigl", "scipy"):
        try:
            out.append(version(dist))
        except PackageNotFoundError:
            out.append(None)
    return tuple(out)
