"""Atomic file writing: write to a temporary sibling, then rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..errors import InputError


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary name keeps the suffix so that writers choosing the format by
    extension still work. On any exception the temporary file is removed and
    ``path`` is left untouched, so a failed write never leaves a partial file.
    """
    path = Path(path)
    _check_replaceable(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".partial" + path.suffix, dir=path.parent)
    except OSError as exc:  # no permission, a read-only or virtual file system, a file in the way
        raise InputError(f"cannot write here: {exc.strerror or exc}", path) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        if tmp.is_file():  # mkstemp makes files private (0600): give them the usual umask mode
            os.chmod(tmp, 0o666 & ~current_umask())
        if tmp.is_dir():  # writers that produce folders (e.g. OpenFOAM cases)
            if path.exists():
                import shutil

                shutil.rmtree(path) if path.is_dir() else path.unlink()
        os.replace(tmp, path)
    except BaseException:
        if tmp.is_dir():
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise


def _check_replaceable(path: Path) -> None:
    """Refuse, before anything is written, to replace a folder holding files that vmesh did
    not write: only an empty folder, an OpenFOAM case (``constant/polyMesh``) or a MeshLab
    export (``vmesh.mlp``) is replaced (``vmesh export -o ~/notes`` removed the folder)."""
    if not path.is_dir() or (path / "constant" / "polyMesh").is_dir() or (path / "vmesh.mlp").is_file():
        return
    names = sorted(p.name for p in path.iterdir())
    if names:
        shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        raise InputError(f"is a folder with other files ({shown}), not an OpenFOAM case or MeshLab export "
                         "vmesh wrote: not replaced (give a new or empty folder)", path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically and return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def replace_dir(stage: str | Path, final: str | Path) -> Path:
    """Put the folder ``stage`` in place of ``final`` by renames (same file system): an
    earlier ``final`` is moved aside, then removed once ``stage`` has taken its name, and
    put back if that rename fails. ``stage`` gets the usual umask mode (``mkdtemp`` made it
    private)."""
    import shutil

    stage, final = Path(stage), Path(final)
    stage.chmod(0o777 & ~current_umask())
    old = None
    if final.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
        old.rmdir()
        final.rename(old)
    try:
        stage.rename(final)
    except OSError:
        if old is not None:
            old.rename(final)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return final


def current_umask() -> int:
    """The process umask, read without setting it (``os.umask`` changes it for every
    thread while it is read, and batch workers are threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022
