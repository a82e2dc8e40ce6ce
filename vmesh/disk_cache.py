"""Results of deterministic, costly steps kept on disk between runs, keyed by their inputs' content.

Re-meshing the same vessel with other meshing parameters is the common case (tuning element
counts, boundary layers, optimiser settings), and a new process redoes the same
preprocessing each time: pymeshlab's quadric decimation of a 150,000-triangle surface alone
is ~2.3 s CPU, the largest step before the mesher. :func:`store` keeps such a step's
output arrays (:func:`load` reads them back) under a key that hashes every input array's
bytes and every option, so a hit returns exactly what the step would compute (same
bytes), and any change to the surface or an option misses.

The folder is ``$VMESH_CACHE_DIR/<kind>`` when that is set, else
``$XDG_CACHE_HOME/vmesh/<kind>`` (``~/.cache/vmesh/<kind>``), beside the compiled kernels
(:mod:`vmesh.numba_cache`). ``VMESH_DISK_CACHE=0`` turns it off; the newest
:data:`KEEP` entries per kind are kept. A folder that cannot be written, or an entry that
cannot be read, only means the step runs.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import pickle
import tempfile

import numpy as np

#: entries kept per kind (the oldest by modification time are removed)
KEEP = 32


def enabled() -> bool:
    """False when ``VMESH_DISK_CACHE`` is ``0``, ``false``, ``no`` or ``off``."""
    return os.environ.get("VMESH_DISK_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")


def user_cache_home() -> pathlib.Path:
    """``$XDG_CACHE_HOME/vmesh`` (``~/.cache/vmesh``): the default home of every vmesh cache,
    these results and the compiled kernels (:func:`vmesh.numba_cache.cache_root`)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "vmesh"


def cache_dir(kind: str) -> pathlib.Path:
    """The folder of the entries of one kind of result."""
    root = os.environ.get("VMESH_CACHE_DIR")
    return (pathlib.Path(root) if root else user_cache_home()) / kind


def key(*parts) -> str:
    """Hex digest over ``parts``: arrays by dtype, shape and bytes, anything else by ``repr``."""
    h = hashlib.blake2b(digest_size=20)
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"array {a.dtype.str} {a.shape}".encode())
            h.update(a.data)
        else:
            h.update(repr(p).encode())
        h.update(b"\0")
    return h.hexdigest()


def load(kind: str, digest: str) -> dict | None:
    """The arrays stored under ``digest``, or None (missing, unreadable, or caching off)."""
    if not enabled():
        return None
    path = cache_dir(kind) / f"{digest}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
    except Exception:  # missing, truncated or not an npz (zipfile, EOF, value errors): run the step
        return None
    _touch(path)
    return out


def store(kind: str, digest: str, arrays: dict) -> bool:
    """Write ``arrays`` under ``digest`` (atomically: a temporary file renamed) and prune
    the kind's folder to :data:`KEEP` entries; False where nothing could be written."""
    if not enabled():
        return False
    try:
        _write(kind, f"{digest}.npz", lambda f: np.savez(f, **arrays))
    except OSError:
        return False
    prune(kind)
    return True


def load_object(kind: str, digest: str):
    """The object pickled under ``digest`` (:func:`store_object`), or None (missing,
    unreadable, written by other code, or caching off)."""
    if not enabled():
        return None
    path = cache_dir(kind) / f"{digest}.pkl"
    try:
        with open(path, "rb") as f:
            out = pickle.load(f)
    except Exception:  # missing, truncated, a class that no longer unpickles: run the steps
        return None
    _touch(path)
    return out


def store_object(kind: str, digest: str, obj, keep: int = KEEP) -> bool:
    """Pickle ``obj`` under ``digest`` (atomically, as :func:`store`) and prune the kind's
    folder to ``keep`` entries; False where nothing could be written (also an object that
    cannot be pickled)."""
    if not enabled():
        return False
    try:
        _write(kind, f"{digest}.pkl", lambda f: pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception:  # a full or read-only disk, an object that cannot be pickled: not kept
        return False
    prune(kind, keep, suffix=".pkl")
    return True


def _write(kind: str, name: str, write) -> None:
    """``write(file)`` into ``<kind>/<name>`` through a temporary file renamed over it (a
    reader never sees half a file); the temporary file is removed when ``write`` fails."""
    folder = cache_dir(kind)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, folder / name)
    except BaseException:
        pathlib.Path(tmp).unlink(missing_ok=True)
        raise


def _touch(path: pathlib.Path) -> None:
    try:
        os.utime(path)  # recently used: pruned last
    except OSError:  # a read-only cache still serves
        pass


def prune(kind: str, keep: int = KEEP, suffix: str = ".npz") -> None:
    """Remove all but the ``keep`` most recently used entries (files ``*suffix``) of ``kind``."""
    try:
        entries = sorted(cache_dir(kind).glob(f"*{suffix}"), key=lambda p: p.stat().st_mtime, reverse=True)
        for p in entries[keep:]:
            p.unlink(missing_ok=True)
    except OSError:
        pass
