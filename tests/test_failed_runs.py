"""Failed and stopped runs: no mesh, a clean one-line error, and ``OUT.failed/`` with what
the run reached (log, report, skeleton, files the failing filter wrote), removed by the
next successful run; SIGTERM/SIGINT remove the staging folder; stale staging folders of
killed runs are removed by the next run into the same output."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from hostile_inputs import tube_skeleton, _write_ply, tube
from vmesh.chain import FilterChain
from vmesh.errors import ChainError, MeshingError
from vmesh.io.failed_run import OWNER_FILE, remove_stale_stages
from vmesh.registry import _REGISTRY, register_filter


@pytest.fixture
def tube_files(tmp_path):
    v, f = tube(n_around=24, n_along=30)
    return _write_ply(tmp_path / "tube.ply", v, f), tube_skeleton(tmp_path / "tube.json")


@pytest.fixture
def failing_filters():
    """Two filters that fail after writing a diagnostic file: one with a vmesh error that
    names the file, one with an unexpected Python error."""

    @register_filter("fail_with_file_test", description="Fail naming a file it wrote.", parameters=[], reads=("surface",), category="test")
    def fail_with_file(ctx):
        path = ctx.output_path("invalid_blocks.vtu")
        path.write_text("diagnostic")
        raise MeshingError(f"2 block(s) stay invalid; the invalid block(s) are in {path}")

    @register_filter("fail_unexpectedly_test", description="Fail with a Python error.", parameters=[], reads=("surface",), category="test")
    def fail_unexpectedly(ctx):
        (single,) = [1, 2]  # noqa: F841  (a bug: too many values to unpack)

    yield
    for name in ("fail_with_file_test", "fail_unexpectedly_test"):
        _REGISTRY.pop(name, None)


def test_failed_run_keeps_its_diagnostics(tmp_path, tube_files, failing_filters):
    surface, skeleton = tube_files
    out = tmp_path / "out"
    chain = FilterChain(["repair_surface", "fail_with_file_test"])
    with pytest.raises(MeshingError) as info:
        chain.run(surface=surface, skeleton=skeleton, out_dir=out)
    failed = tmp_path / "out.failed"
    message = str(info.value)
    assert not out.exists() and failed.is_dir()
    assert f"{failed}/invalid_blocks.vtu" in message and ".partial-" not in message  # names the file that persists
    assert (failed / "invalid_blocks.vtu").read_text() == "diagnostic"
    report = json.loads((failed / "report.json").read_text())
    assert report["failed"]["step"] == "fail_with_file_test" and report["steps"][0]["filter"] == "repair_surface"
    assert "repair_surface" in (failed / "failure.log").read_text()
    assert (failed / "skeleton.json").is_file()  # the skeleton reached
    assert not list(tmp_path.glob(".out.*"))  # no staging folder left
    # the next successful run removes it
    FilterChain(["repair_surface"]).run(surface=surface, out_dir=out)
    assert (out / "report.json").is_file() and not failed.exists()


def test_unexpected_error_is_one_line_with_the_traceback_in_the_log(tmp_path, tube_files, failing_filters):
    surface, _ = tube_files
    out = tmp_path / "out"
    with pytest.raises(ChainError) as info:
        FilterChain(["repair_surface", "fail_unexpectedly_test"]).run(surface=surface, out_dir=out)
    message = str(info.value)
    assert "step 2 'fail_unexpectedly_test'" in message and "internal error" in message
    assert "ValueError" not in message and "unpack" not in message  # no Python text
    log = (tmp_path / "out.failed" / "failure.log").read_text()
    assert "Traceback" in log and "ValueError: too many values to unpack" in log
    assert str(tmp_path / "out.failed" / "failure.log") in message


def test_unexpected_error_without_output_folder(tube_files, failing_filters):
    surface, _ = tube_files
    with pytest.raises(ChainError, match="vmesh --debug shows the traceback"):
        FilterChain(["fail_unexpectedly_test"]).run(surface=surface)


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_staging_folders_are_removed(tmp_path, tube_files):
    surface, _ = tube_files
    out = tmp_path / "out"
    dead = tmp_path / ".out.partial-dead"
    dead.mkdir()
    (dead / OWNER_FILE).write_text(f"{_dead_pid()} {os.uname().nodename}\n")
    alive = tmp_path / ".out.partial-alive"
    alive.mkdir()
    (alive / OWNER_FILE).write_text(f"{os.getpid()} {os.uname().nodename}\n")
    unowned_old = tmp_path / ".out.partial-old"
    unowned_old.mkdir()
    os.utime(unowned_old, (time.time() - 3600, time.time() - 3600))
    half_swapped = tmp_path / ".out.old-x"
    half_swapped.mkdir()
    other = tmp_path / ".other.partial-dead"
    other.mkdir()
    FilterChain(["repair_surface"]).run(surface=surface, out_dir=out)
    assert not dead.exists() and not unowned_old.exists() and not half_swapped.exists()
    assert alive.exists() and other.exists()  # a running run's folder, another output's folder
    assert remove_stale_stages(out) == []


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_stopped_run_removes_its_staging_folder(tmp_path, tube_files, sig):
    surface, _ = tube_files
    out = tmp_path / "out"
    # no centerline: the extraction keeps it busy for a while
    p = subprocess.Popen([sys.executable, "-m", "vmesh", "run", "default", "-i", str(surface), "-o", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not list(tmp_path.glob(".out.partial-*")) and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)
    assert list(tmp_path.glob(".out.partial-*")), "the run never started staging"
    time.sleep(0.5)
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + sig, err[-2000:]
    errors = [line for line in err.splitlines() if line.startswith("vmesh: error:")]
    assert len(errors) == 1 and f"stopped by {signal.Signals(sig).name}" in errors[0], err[-2000:]
    assert "Traceback" not in err
    assert not list(tmp_path.glob(".out.*")) and not out.exists()
    assert (tmp_path / "out.failed" / "failure.log").is_file() and str(tmp_path / "out.failed") in errors[0]


def test_batch_row_diagnostics_leave_the_staging_folder(tmp_path):
    """A failed batch row's OUT.failed/ moves out of the batch's staging folder (removed
    at the end of a batch) to OUT/<name>.failed/, and the error names the new place."""
    from vmesh.batch import _keep_row_diagnostics

    tmp = tmp_path / ".vmesh-batch" / "row.abc"
    left = tmp_path / ".vmesh-batch" / "row.abc.failed"
    left.mkdir(parents=True)
    (left / "failure.log").write_text("log")
    error = _keep_row_diagnostics(tmp, tmp_path / "row.failed", f"step 9: see {left}/invalid_blocks.vtu")
    assert (tmp_path / "row.failed" / "failure.log").is_file() and not left.exists()
    assert error == f"step 9: see {tmp_path / 'row.failed'}/invalid_blocks.vtu"
    assert _keep_row_diagnostics(tmp_path / "other", tmp_path / "other.failed", "x") == "x"


def test_a_stop_lost_in_a_finaliser_is_sent_again(monkeypatch):
    """A signal whose handler runs inside a ``__del__`` (llvmlite's, while numba compiles)
    raises where Python can only print "Exception ignored" and go on: the command line's
    unraisable hook sends the signal again (the run then stops at its next step) and prints
    no traceback; other finaliser errors are silent unless --debug."""
    import types

    from vmesh import cli
    from vmesh.errors import Stopped

    sent, printed = [], []
    monkeypatch.setattr(cli.os, "kill", lambda pid, sig: sent.append(sig))
    hook = cli._unraisable_hook(printed.append, debug=False)
    hook(types.SimpleNamespace(exc_value=Stopped("SIGTERM", signal.SIGTERM)))
    hook(types.SimpleNamespace(exc_value=KeyboardInterrupt()))
    hook(types.SimpleNamespace(exc_value=ValueError("in a finaliser")))
    assert sent == [signal.SIGTERM, signal.SIGINT] and printed == []
    cli._unraisable_hook(printed.append, debug=True)(types.SimpleNamespace(exc_value=ValueError("x")))
    assert len(printed) == 1


def test_a_stop_inside_an_import_is_a_stop_not_a_bug(tmp_path, tube_files):
    """A SIGINT that lands while a C extension initialises (scipy.optimize's HiGHS module,
    imported lazily in clean_skeleton) comes back as ``ImportError: initialization failed``
    caused by the KeyboardInterrupt: the run must stop as stopped runs do (exit 130 on the
    command line, OUT.failed/ says so), never as "an internal error"."""
    surface, _ = tube_files

    @register_filter("stop_inside_import_test", description="Fail as an interrupted import does.", parameters=[], reads=("surface",), category="test")
    def stop_inside_import(ctx):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    try:
        with pytest.raises(KeyboardInterrupt):
            FilterChain(["repair_surface", "stop_inside_import_test"]).run(surface=surface, out_dir=tmp_path / "out")
        assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.partial-*"))
        assert "SIGINT" in (tmp_path / "out.failed" / "failure.log").read_text()
    finally:
        _REGISTRY.pop("stop_inside_import_test", None)


def test_a_stop_inside_an_import_turned_into_a_vmesh_error_is_a_stop(tmp_path, tube_files):
    """A filter that reports an interrupted import as its own (vmesh) error still stops the
    run as a stop, not as that step's error."""
    from vmesh.errors import InputError

    surface, _ = tube_files

    @register_filter("stop_as_vmesh_error_test", description="Report an interrupted import as a vmesh error.", parameters=[], reads=("surface",), category="test")
    def stop_as_vmesh_error(ctx):
        try:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise ImportError("initialization failed") from exc
        except ImportError as exc:
            raise InputError("a reader is missing") from exc

    try:
        with pytest.raises(KeyboardInterrupt):
            FilterChain(["repair_surface", "stop_as_vmesh_error_test"]).run(surface=surface, out_dir=tmp_path / "out")
        assert not (tmp_path / "out").exists()
    finally:
        _REGISTRY.pop("stop_as_vmesh_error_test", None)


@pytest.mark.parametrize("stopped", [True, False])
def test_render_setup_passes_a_stop_inside_vtks_import_on(monkeypatch, stopped):
    """``render._setup`` goes on without VTK's logger settings when the import fails, but a
    stop that landed during that import is raised."""
    import builtins

    pytest.importorskip("pyvista")
    from vmesh import render

    real = builtins.__import__

    def fake(name, *args, **kwargs):
        if name == "vtk":
            if not stopped:
                raise ImportError("no vtk")
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise ImportError("initialization failed") from exc
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake)
    if stopped:
        with pytest.raises(KeyboardInterrupt):
            render._setup()
    else:
        assert render._setup() is not None


def test_stop_behind_follows_causes_and_contexts():
    from vmesh.errors import Stopped, stop_behind

    try:
        try:
            raise Stopped("SIGTERM", signal.SIGTERM)
        except Stopped:
            raise ImportError("initialization failed")  # context, not cause
    except ImportError as exc:
        assert isinstance(stop_behind(exc), Stopped)
    assert stop_behind(ValueError("x")) is None
