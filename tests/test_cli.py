"""The command line: discovery, bad inputs (one line, exit 2, nothing written)."""

import subprocess
import sys

import pytest

import vmesh


def vmesh_cli(*args, cwd=None):
    """``python -m vmesh ARGS`` in a new process (about 1 s of imports each)."""
    return subprocess.run([sys.executable, "-m", "vmesh", *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.fixture
def vmesh_main(capfd, monkeypatch):
    """``vmesh_main(*args)`` runs the command in this process, as ``python -m vmesh`` does
    (``sys.exit(main())``), and returns what ``vmesh_cli`` returns: the exit status and the
    text written to stdout and stderr, captured at the file descriptors (so that a line a
    compiled library writes counts too). One real process per test module is enough to
    cover the entry point; the rest save the interpreter's start."""
    from vmesh.cli import main

    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)  # main() wraps it; undone after the test

    def run(*args):
        capfd.readouterr()
        try:
            code = main(list(map(str, args)))
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code
        out, err = capfd.readouterr()
        return subprocess.CompletedProcess(["vmesh", *map(str, args)], code, out, err)

    return run


def test_filters_lists_every_filter(vmesh_main):
    r = vmesh_main("filters")
    assert r.returncode == 0
    for name in vmesh.filter_list():
        assert name in r.stdout


def test_filters_name_prints_parameters(capsys):
    from vmesh.cli import main

    r = vmesh_cli("filters", "mesh_transfinite")  # one real process; the rest in-process (fast)
    assert r.returncode == 0 and "order : int = 1" in r.stdout
    for name in vmesh.filter_list():
        assert main(["filters", name]) == 0
        out = capsys.readouterr().out
        f = vmesh.get_filter(name)
        for p in f.parameters:
            assert f"{p.name} : {p.type}" in out


def test_unknown_filter_name(vmesh_main):
    r = vmesh_main("filters", "mesh_transfinit")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "did you mean 'mesh_transfinite'" in r.stderr


def _bad_inputs(tmp_path):
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    corrupt = tmp_path / "corrupt.ply"
    corrupt.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    unknown = tmp_path / "surface.xyz"
    unknown.write_text("1 2 3\n")
    return {
        "missing": (tmp_path / "nope.stl", "file not found"),
        "empty": (empty, "file is empty"),
        "corrupt": (corrupt, "corrupt"),
        "unknown": (unknown, "unknown surface format"),
    }


@pytest.mark.parametrize("case", ["missing", "empty", "corrupt", "unknown"])
def test_bad_surface_inputs(tmp_path, case, vmesh_main):
    path, message = _bad_inputs(tmp_path)[case]
    out = tmp_path / "out"
    r = vmesh_main("run", "default", "--input", path, "--out", out)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vmesh: error:") and str(path) in lines[0] and message in lines[0], r.stderr
    assert not out.exists()


def test_bad_skeleton_file(tmp_path, vmesh_main):
    from conftest import synthetic_case

    surface, _ = synthetic_case("straight_tube")
    if not surface.exists():
        pytest.skip("synthetic data not generated")
    skel = tmp_path / "skel.json"
    skel.write_text('{"nodes": [{"id": 0, "xyz": [0, 0]}], "edges": []')
    out = tmp_path / "out"
    r = vmesh_main("run", "default", "--input", surface, "--skeleton", skel, "--out", out)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert str(skel) in r.stderr and "JSON" in r.stderr
    assert not out.exists()


def test_bad_set_values(tmp_path, vmesh_main):
    r = vmesh_main("run", "default", "--input", tmp_path / "x.stl", "--set", "mesh_transfinite.order=9")
    assert r.returncode == 2 and "above its maximum" in r.stderr
    r = vmesh_main("run", "default", "--set", "oops")
    assert r.returncode == 2 and "filter.param=value" in r.stderr


def test_info(tmp_path, vmesh_main):
    import numpy as np
    import pyvista as pv

    path = tmp_path / "c.stl"
    pv.Cylinder(resolution=16).triangulate().save(path)
    r = vmesh_main("info", path)
    assert r.returncode == 0 and "open boundary loops 0" in r.stdout and "outward" in r.stdout


def test_skeleton_command_repairs_inconsistent_orientation(tmp_path, capsys):
    """`vmesh skeleton` repairs the surface first, as `vmesh run default` does (it stopped
    at cap_open_ends on a surface with inconsistently oriented faces)."""
    import numpy as np

    from hostile_inputs import _write_ply, tube, tube_skeleton
    from vmesh.cli import main

    v, f = tube(n_around=24, n_along=30)
    flip = np.random.default_rng(0).random(len(f)) < 0.3
    f[flip] = f[flip][:, ::-1]
    surface = _write_ply(tmp_path / "mixed_orientation.ply", v, f)
    centerline = tube_skeleton(tmp_path / "centerline.json")
    out = tmp_path / "skel.json"
    code = main(["skeleton", str(surface), "--skeleton", str(centerline), "--out", str(out), "--no-png", "-q"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert out.is_file() and "repair_surface" not in captured.err


def test_internal_error_is_one_line(tmp_path, capsys, monkeypatch):
    """A bug outside any filter still prints one line, with the traceback in a log file."""
    from vmesh import cli

    def broken(path):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr("vmesh.io.surface.read_surface", broken)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    path = tmp_path / "c.stl"
    path.write_text("solid\nendsolid\n")
    code = cli.main(["info", str(path)])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == cli.EXIT_INTERNAL and len(lines) == 1 and lines[0].startswith("vmesh: error: 'info' stopped on an internal error")
    assert "ZeroDivisionError" not in err
    (log,) = tmp_path.glob("vmesh-error-*.log")
    assert "ZeroDivisionError: division by zero" in log.read_text() and str(log) in err
