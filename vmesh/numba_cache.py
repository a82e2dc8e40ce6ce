"""Where vmesh's compiled numba kernels are cached: one folder per kernel module and version of its sources.

numba's own locators key a cache on the source file's *path* (``__pycache__`` beside the
file, or a hash of its folder under ``$NUMBA_CACHE_DIR``), so every new clone, virtual
environment or worktree of vmesh compiles all its kernels again (~40 s CPU on a 2-core
machine), although the sources are the same. Here the cache folder is keyed on the
*content* of the sources instead:

    <root>/<numba version>/<module>-<SHA-1 of the module and the kernel modules it imports>/

with ``<root>`` = ``$NUMBA_CACHE_DIR/vmesh`` when that is set, else
``$XDG_CACHE_HOME/vmesh/numba`` (``~/.cache/vmesh/numba``). A second installation of the
same sources on a machine loads the first one's kernels. The digest covers the kernel
modules a module imports (transitively) because kernels call, and inline, each other across
modules (the octree's queries inline the BVH's point-triangle test): numba's per-file stamp
would keep a caller compiled against an old callee. numba still checks the CPU and its own
version per entry. A kernel module is one that uses ``njit`` or ``@intrinsic``.

Other packages' kernels keep numba's locators; so does vmesh when no folder is writable
(or with ``VMESH_NUMBA_CACHE=path``).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import os
import pathlib
import re
import shutil

from numba.core import caching, config

from .disk_cache import user_cache_home
from .source_imports import imported_names

PACKAGE = pathlib.Path(__file__).resolve().parent
KEEP = 8  # source versions kept side by side per module (worktrees, branches); older ones are removed
_KERNELS = re.compile(rb"\bnjit\b|@intrinsic")


@functools.lru_cache(maxsize=None)  # closures overlap: each file is read and parsed once
def _is_kernel_module(path: pathlib.Path) -> bool:
    return path.suffix == ".py" and path.is_file() and _KERNELS.search(path.read_bytes()) is not None


def _statements(tree: ast.Module):
    """Every statement of ``tree``, nested ones included, without visiting expressions.

    Import statements can only be statements, and statements only sit in the statement
    lists of other statements (bodies, ``else``/``finally`` blocks, ``except`` handlers,
    ``match`` cases), never inside an expression: this finds the same imports as
    ``ast.walk`` while skipping the expression nodes, most of a module's tree (the walk was
    ~60 % of the ~0.1 s CPU every run spent on the 12 kernel modules' digests)."""
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        yield node
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            for child in getattr(node, field, ()):
                if isinstance(child, ast.stmt):
                    todo.append(child)
                else:  # an except handler or a match case: its body holds statements
                    todo.extend(child.body)


@functools.lru_cache(maxsize=None)
def _imported_modules(path: pathlib.Path) -> frozenset[pathlib.Path]:
    """The vmesh modules ``path`` imports (relative or ``vmesh.`` imports), as files."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    package = ".".join(parts if path.name == "__init__.py" else parts[:-1])
    found = set()
    for node in _statements(ast.parse(path.read_bytes())):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            for name in imported_names(node, package):
                stem = PACKAGE.parent.joinpath(*name.split("."))
                found.update(p for p in (stem.with_suffix(".py"), stem / "__init__.py") if p.is_file())
    return frozenset(found)


def kernel_closure(py_file: str) -> list[pathlib.Path]:
    """The kernel module ``py_file`` and every kernel module it imports, directly or through
    other kernel modules (their kernels may be compiled into its own), sorted."""
    closure, todo = set(), [pathlib.Path(py_file).resolve()]
    while todo:
        p = todo.pop()
        if p not in closure:
            closure.add(p)
            todo.extend(q for q in _imported_modules(p) if _is_kernel_module(q))
    return sorted(closure)


@functools.lru_cache(maxsize=None)
def sources_digest(py_file: str) -> str:
    """SHA-1 over the paths (relative to the package) and contents of :func:`kernel_closure`."""
    h = hashlib.sha1()
    for p in kernel_closure(py_file):
        h.update(p.relative_to(PACKAGE).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def cache_root() -> pathlib.Path:
    """The folder holding one subfolder per numba version."""
    if config.CACHE_DIR:
        return pathlib.Path(config.CACHE_DIR) / "vmesh"
    return user_cache_home() / "numba"


def _module_name(py_file: str) -> str:
    return pathlib.Path(py_file).resolve().relative_to(PACKAGE).with_suffix("").as_posix().replace("/", ".")


def cache_folder(py_file: str) -> pathlib.Path:
    """The cache of the kernels of module ``py_file`` in this version of its sources."""
    import numba

    return cache_root() / numba.__version__ / f"{_module_name(py_file)}-{sources_digest(py_file)[:20]}"


def prune(py_file: str, keep: int = KEEP) -> list[pathlib.Path]:
    """Remove all but the ``keep`` most recently written source versions of module ``py_file``'s
    cache; returns those removed."""
    mine = cache_folder(py_file)
    prefix = mine.name.rsplit("-", 1)[0] + "-"
    others = [p for p in mine.parent.glob(prefix + "*") if p.is_dir() and p != mine and p.name.rsplit("-", 1)[0] + "-" == prefix]
    others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    old = others[max(keep - 1, 0):]
    for p in old:
        shutil.rmtree(p, ignore_errors=True)
    return old


class ContentCacheLocator(caching._CacheLocator):
    """numba cache locator for vmesh's kernels: the folder is :func:`cache_folder`, the
    freshness stamp the digest of all kernel sources, the disambiguator the line number."""

    def __init__(self, py_func, py_file):
        self._lineno = py_func.__code__.co_firstlineno
        self._py_file = py_file
        self._cache_path = str(cache_folder(py_file))

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return sources_digest(self._py_file)

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
            prune(py_file)
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
