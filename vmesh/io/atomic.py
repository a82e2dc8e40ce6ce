"""Atomic file writing: write to a temporary sibling, then rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..errors import InputError


@contextlib.contextmanager
def atomic_path(path: str | Path, folder: bool = False):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary name keeps the suffix so that writers choosing the format by
    extension still work. On any exception the temporary file is removed and
    ``path`` is left untouched, so a failed write never leaves a partial file.

    Before anything is written, :func:`check_replaceable` refuses (``InputError``) a
    ``path`` that is a folder vmesh may not replace: any folder for a file writer, and a
    folder of other files for a folder writer (``folder=True``: an OpenFOAM case, a
    MeshLab export, which then turns the yielded file into a folder).
    """
    path = Path(path)
    check_replaceable(path, folder)
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


def check_replaceable(path: str | Path, folder: bool = False) -> None:
    """Refuse (``InputError``), before anything is written, to replace a folder that is not
    vmesh's to replace (``vmesh export -o ~/notes`` once removed the folder).

    A file writer (``folder=False``) never replaces a folder. A folder writer replaces an
    empty folder, an OpenFOAM case vmesh wrote (its ``constant/polyMesh`` files carry the
    ``Written by vmesh`` header) or a MeshLab export (a ``*.mlp`` project at its top);
    not a folder of other files, nor an OpenFOAM case written by something else."""
    path = Path(path)
    if not path.is_dir():
        return
    if not folder:
        raise InputError("is a folder: not replaced by a file (give a file name)", path)
    try:
        if _vmesh_case(path) or any(p.suffix.lower() == ".mlp" and p.is_file() for p in path.iterdir()):
            return
        names = sorted(p.name for p in path.iterdir())
    except OSError as exc:  # an unreadable folder
        raise InputError(f"cannot read this folder: {exc.strerror or exc}", path) from None
    if not names:
        return
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    what = ("an OpenFOAM case vmesh did not write" if (path / "constant" / "polyMesh").is_dir()
            else f"a folder with other files ({shown}), not an OpenFOAM case or MeshLab export vmesh wrote")
    raise InputError(f"is {what}: not replaced (give a new or empty folder)", path)


def _vmesh_case(path: Path) -> bool:
    """Whether ``path`` is an OpenFOAM case written by vmesh: the header of its
    ``constant/polyMesh/boundary`` (or ``points``) names vmesh."""
    for name in ("boundary", "points"):
        f = path / "constant" / "polyMesh" / name
        if f.is_file():
            with open(f, "rb") as fh:
                if b"Written by vmesh" in fh.read(1024):
                    return True
    return False


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
