"""Where vmesh's compiled numba kernels are cached: one folder per version of the kernel sources.

numba's own locators key a cache on the source file's *path* (``__pycache__`` beside the
file, or a hash of its folder under ``$NUMBA_CACHE_DIR``), so every new clone, virtual
environment or worktree of vmesh compiles all its kernels again (~40 s CPU on a 2-core
machine), although the sources are the same. Here the cache folder is keyed on the
*content* of vmesh's kernel sources instead:

    <root>/<numba version>/<SHA-1 of every vmesh module that uses numba>/

with ``<root>`` = ``$NUMBA_CACHE_DIR/vmesh`` when that is set, else
``$XDG_CACHE_HOME/vmesh/numba`` (``~/.cache/vmesh/numba``). A second installation of the
same sources on a machine loads the first one's kernels. One digest over *all* kernel
modules, not one per file, because kernels call each other across modules (the octree's
queries inline the BVH's point-triangle test): numba's per-file stamp would keep a caller
compiled against an old callee. numba still checks the CPU and its own version per entry.

Other packages' kernels keep numba's locators; so does vmesh when no folder is writable.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import shutil

from numba.core import caching, config

PACKAGE = pathlib.Path(__file__).resolve().parent
KEEP = 8  # source versions kept side by side (worktrees, branches); older folders are removed


def _kernel_sources() -> list[pathlib.Path]:
    """vmesh's modules that use numba (read once per process)."""
    return sorted(p for p in PACKAGE.rglob("*.py") if b"numba" in p.read_bytes())


_DIGEST: list[str] = []


def sources_digest() -> str:
    """SHA-1 over the paths (relative to the package) and contents of the kernel modules."""
    if not _DIGEST:
        h = hashlib.sha1()
        for p in _kernel_sources():
            h.update(p.relative_to(PACKAGE).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
        _DIGEST.append(h.hexdigest())
    return _DIGEST[0]


def cache_root() -> pathlib.Path:
    """The folder holding one subfolder per numba version and source digest."""
    if config.CACHE_DIR:
        return pathlib.Path(config.CACHE_DIR) / "vmesh"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "vmesh" / "numba"


def cache_folder() -> pathlib.Path:
    """This installation's kernel cache."""
    import numba

    return cache_root() / numba.__version__ / sources_digest()


def prune(keep: int = KEEP) -> list[pathlib.Path]:
    """Remove all but the ``keep`` most recently written source versions; returns those removed."""
    import numba

    version = cache_root() / numba.__version__
    if not version.is_dir():
        return []
    mine = cache_folder()
    folders = sorted((p for p in version.iterdir() if p.is_dir() and p != mine), key=lambda p: p.stat().st_mtime, reverse=True)
    old = folders[max(keep - 1, 0):]
    for p in old:
        shutil.rmtree(p, ignore_errors=True)
    return old


class ContentCacheLocator(caching._CacheLocator):
    """numba cache locator for vmesh's kernels: the folder is :func:`cache_folder`, the
    freshness stamp the digest of all kernel sources, the disambiguator the line number."""

    def __init__(self, py_func, py_file):
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = str(cache_folder())

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return sources_digest()

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            if not pathlib.Path(py_file).resolve().is_relative_to(PACKAGE):
                return None
            self = cls(py_func, py_file)
            new = not os.path.isdir(self._cache_path)
            self.ensure_cache_path()
        except OSError:
            return None  # no writable folder: numba's own locators
        if new:
            prune()
        return self


def install() -> None:
    """Put :class:`ContentCacheLocator` first in numba's locator list (before any vmesh kernel
    is decorated; ``vmesh/__init__.py`` calls it). ``VMESH_NUMBA_CACHE=path`` restores
    numba's path-keyed locators."""
    if os.environ.get("VMESH_NUMBA_CACHE", "content") == "path":
        return
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # renamed in numba 0.60
    classes = impl._locator_classes
    if ContentCacheLocator not in classes:
        classes.insert(0, ContentCacheLocator)
