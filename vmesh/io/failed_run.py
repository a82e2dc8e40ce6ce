"""What a failed or stopped run leaves for its user: ``OUT.failed/`` beside the output.

A run stages its files in a hidden sibling folder ``.OUT.partial-XXXX`` and moves it onto
``OUT`` only when every step succeeded. When a step fails (or the run is stopped by
SIGINT/SIGTERM) the staging folder becomes ``OUT.failed/`` instead, with what the run
had reached:

``failure.log``
    the steps run (time, counts, warnings), the error line and the full traceback;
``report.json``
    the report so far, with a ``failed`` section (step, filter, error);
``skeleton.json``, ``skeleton.png``
    the skeleton reached, and a picture of it over the surface (when one can be drawn);
and whatever the failed filter wrote there (e.g. ``invalid_blocks.vtu``).

The next successful run into ``OUT`` removes ``OUT.failed/``; every run into ``OUT``
removes staging folders left by runs that were killed (their process is gone).
"""

from __future__ import annotations

import json
import os
import shutil
import time
import traceback
from pathlib import Path

from .atomic import replace_dir

#: Suffix of the folder a failed run leaves beside its output folder.
FAILED_SUFFIX = ".failed"
#: File in a staging folder naming the process that owns it.
OWNER_FILE = ".owner"
#: A staging folder without an owner file is stale once it is this old (seconds).
UNOWNED_GRACE_S = 120.0


def failed_dir(out_dir: str | Path) -> Path:
    """``OUT.failed`` beside ``OUT``."""
    out_dir = Path(out_dir)
    return out_dir.with_name(out_dir.name + FAILED_SUFFIX)


def mark_owner(stage: Path) -> None:
    """Record this process as the owner of the staging folder ``stage``."""
    (stage / OWNER_FILE).write_text(f"{os.getpid()} {os.uname().nodename}\n")


def _owner_alive(stage: Path) -> bool:
    try:
        pid_text, host = (stage / OWNER_FILE).read_text().split()
        pid = int(pid_text)
    except FileNotFoundError:
        # an old run's folder, or one whose owner is writing its file this very moment
        try:
            return time.time() - stage.stat().st_mtime < UNOWNED_GRACE_S
        except OSError:
            return False
    except (OSError, ValueError):
        return False
    if host != os.uname().nodename:
        return True  # another machine's process: cannot tell, leave it
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_stages(out_dir: str | Path) -> list[Path]:
    """Remove the staging folders (``.OUT.partial-*``) and half-swapped folders
    (``.OUT.old-*``) of ``OUT`` whose run is gone (killed); returns what was removed."""
    out_dir = Path(out_dir)
    parent = out_dir.parent
    if not parent.is_dir():
        return []
    removed = []
    for pattern in (f".{out_dir.name}.partial-*", f".{out_dir.name}.old-*"):
        for path in parent.glob(pattern):
            if not path.is_dir() or path.is_symlink():
                continue
            if pattern.endswith("partial-*") and _owner_alive(path):
                continue
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def remove_failed(out_dir: str | Path) -> None:
    """Remove ``OUT.failed`` (after a successful run into ``OUT``)."""
    path = failed_dir(out_dir)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)


def _write(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError:
        pass


def write_diagnostics(stage: Path, ctx, error_line: str, step: str | None, exc: BaseException | None) -> None:
    """Write ``failure.log``, ``report.json`` (so far) and the skeleton reached into ``stage``.

    Never raises: a diagnostic that cannot be written is left out.
    """
    report = {}
    try:
        report = ctx.report.to_dict()
    except Exception:  # a half-built report section must not hide the failure
        pass
    report["inputs"] = dict(getattr(ctx, "inputs", {}) or {})
    report["failed"] = {"step": step, "error": error_line}
    _write(stage / "report.json", json.dumps(report, indent=2, default=str))
    lines = [f"vmesh run failed at {time.strftime('%Y-%m-%d %H:%M:%S')}", f"error: {error_line}", "", "steps:"]
    for s in ctx.report.steps:
        counts = ", ".join(f"{k}={v}" for k, v in s.counts.items())
        lines.append(f"  {s.filter:<24} {s.seconds:8.2f} s  {counts}")
    lines.append(f"  {step or '-':<24} (failed)")
    if ctx.report.warnings:
        lines += ["", "warnings:"] + [f"  {w}" for w in ctx.report.warnings]
    if exc is not None:
        lines += ["", "traceback:", "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))]
    _write(stage / "failure.log", "\n".join(lines) + "\n")
    if ctx.skeleton is not None:
        try:
            from .skeleton import write_skeleton

            write_skeleton(stage / "skeleton.json", ctx.skeleton)
        except Exception:
            pass
        if os.environ.get("VMESH_NO_RENDER") is None:
            try:
                from ..filters.skeleton_filters import render_skeleton_png

                render_skeleton_png(stage / "skeleton.png", ctx.skeleton, ctx.surface, title=f"reached before {step or 'the failure'}")
            except Exception:  # no OpenGL context, or a skeleton that cannot be drawn
                pass


def keep_failed(stage: Path, out_dir: Path) -> Path:
    """Move the staging folder onto ``OUT.failed`` (replacing an earlier one)."""
    for name in (OWNER_FILE,):
        (stage / name).unlink(missing_ok=True)
    return replace_dir(stage, failed_dir(out_dir))
