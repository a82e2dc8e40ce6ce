"""Hostile inputs through the command line: every run either gives a valid mesh or fails
with one ``vmesh: error:`` line (no Python text), and never leaves a half-written output.

The inputs are generated (tests/hostile_inputs.py): a small tube with stray line and
vertex cells, degenerate triangles, duplicated vertices, a hole in the wall, a pinched
(self-touching) middle, tiny and huge coordinates, NaN coordinates, a volume mesh, quads,
several pieces; and files that are no mesh at all.
"""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from hostile_inputs import HOSTILE_INPUTS

#: Python's own words: a traceback, or an exception or warning class name.
PYTHON_TEXT = re.compile(r"Traceback|File \"|\b[A-Z][A-Za-z]*(Error|Exception|Warning)\b")

#: Inputs that are no surface at all: the reader must refuse them (fast).
NOT_MESHES = ("empty_file", "not_a_mesh", "binary_garbage", "nan_coordinates", "only_lines")

#: Inputs that are meshable after repair: the run must give a valid mesh.
MESHABLE = ("stray_cells", "degenerate_triangles", "duplicated_vertices", "hole_in_wall", "volume_mesh", "mixed_quads", "two_pieces",
            "tiny", "huge")


def run_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "vmesh", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def check_outcome(r, out):
    """A valid mesh, or one clean error line and no output; returns the report or None."""
    leftovers = sorted(p.name for p in out.parent.glob(f".{out.name}.*"))
    assert not leftovers, f"staging folders left: {leftovers}"
    assert not PYTHON_TEXT.search(r.stderr), r.stderr[-2000:]
    errors = [line for line in r.stderr.splitlines() if line.startswith("vmesh: error:")]
    if r.returncode != 0:
        assert len(errors) == 1, r.stderr[-2000:]
        assert not out.exists(), "a failed run must not write its output folder"
        return None
    assert not errors
    import pyvista as pv

    grid = pv.read(str(out / "mesh.vtu"))
    assert grid.n_cells > 0
    report = json.loads((out / "report.json").read_text())
    sj = report["quality"]["scaled_jacobian"]
    assert sj["n_invalid"] == 0 and sj["min"] > 0
    assert np.all(np.asarray(grid.cell_data["scaled_jacobian"]) > 0)
    return report


class _Result:
    def __init__(self, returncode, stderr):
        self.returncode, self.stderr = returncode, stderr


@pytest.fixture
def run_main(capfd, monkeypatch):
    """``run_main(*args)``: the command line in this process, its stderr captured at the file
    descriptor (a compiled library's lines count too); returns what ``run_cli`` returns. A
    real process costs about 1 s of imports per run: `test_not_a_mesh_in_a_real_process`
    covers the entry point, the meshing runs go in-process."""
    from vmesh.cli import main

    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)  # main() wraps it; undone after the test

    def run(*args):
        capfd.readouterr()
        code = main(list(map(str, args)))
        return _Result(code, capfd.readouterr().err)

    return run


@pytest.mark.parametrize("name", NOT_MESHES)
def test_not_a_mesh_is_refused_in_one_line(tmp_path, capsys, name):
    from vmesh.cli import main

    surface, skeleton = HOSTILE_INPUTS[name](tmp_path)
    out = tmp_path / "out"
    code = main(["run", "default", "-q", "-i", str(surface), "-o", str(out), *(["-s", str(skeleton)] if skeleton else [])])
    r = _Result(code, capsys.readouterr().err)
    assert r.returncode == 2
    assert check_outcome(r, out) is None
    assert str(surface) in r.stderr  # the error names the file
    assert not (tmp_path / "out.failed").exists()  # nothing ran: nothing to inspect


def test_not_a_mesh_in_a_real_process(tmp_path):
    surface, _ = HOSTILE_INPUTS["binary_garbage"](tmp_path)
    r = run_cli("run", "default", "-i", surface, "-o", tmp_path / "out")
    assert r.returncode == 2 and check_outcome(r, tmp_path / "out") is None


@pytest.mark.slow
@pytest.mark.parametrize("name", MESHABLE)
def test_repairable_input_meshes(tmp_path, name, run_main):
    surface, skeleton = HOSTILE_INPUTS[name](tmp_path)
    out = tmp_path / "out"
    r = run_main("run", "default", "-q", "-i", surface, "-s", skeleton, "-o", out)
    report = check_outcome(r, out)
    assert report is not None, r.stderr[-2000:]
    if name == "hole_in_wall":
        assert len(report["repair"]["filled_holes"]) == 1
    if name == "two_pieces":
        dropped = report["surface"]["dropped_components"]
        assert len(dropped) == 1 and dropped[0]["faces"] == 12 and report["surface"]["debris_components"] == 1
        assert any("separate pieces" in w for w in report["warnings"])
    if name == "stray_cells":
        assert any("dropped 2 line and 1 vertex cell" in w for w in report["warnings"])
    if name == "volume_mesh":
        assert any("volume mesh" in w for w in report["warnings"])


@pytest.mark.slow
def test_self_touching_vessel_meshes_or_fails_cleanly(tmp_path, run_main):
    surface, skeleton = HOSTILE_INPUTS["self_touching"](tmp_path)
    out = tmp_path / "out"
    r = run_main("run", "default", "-q", "-i", surface, "-s", skeleton, "-o", out)
    if check_outcome(r, out) is None:
        assert (tmp_path / "out.failed" / "failure.log").is_file()
        assert f"{tmp_path / 'out.failed'}/" in r.stderr


@pytest.mark.slow
def test_hostile_inputs_with_extracted_skeleton(tmp_path, run_main):
    """Without a centerline the extraction runs on the repaired surface."""
    for name in ("stray_cells", "two_pieces", "hole_in_wall"):
        d = tmp_path / name
        d.mkdir()
        surface, _ = HOSTILE_INPUTS[name](d)
        out = d / "out"
        check_outcome(run_main("run", "default", "-q", "-i", surface, "-o", out), out)


# -- repairs, in process (fast) ------------------------------------------------------------
def _repair_chain(path, **params):
    from vmesh.chain import FilterChain

    return FilterChain([("repair_surface", params)]).run(surface=path)


def test_several_pieces_keep_the_largest_and_name_the_others(tmp_path):
    surface, _ = HOSTILE_INPUTS["two_pieces"](tmp_path)
    ctx = _repair_chain(surface)
    assert ctx.surface.info().n_components == 1 and ctx.surface.vertices[:, 0].max() <= 40.0 + 1e-9
    dropped = ctx.report.sections["surface"]["dropped_components"]
    assert len(dropped) == 1
    box = dropped[0]
    assert box["faces"] == 12 and np.allclose(box["bbox_min"], [100, 0, 0]) and np.allclose(box["bbox_max"], [102, 2, 2])
    assert ctx.report.sections["surface"]["debris_components"] == 1  # the tiny triangle: counted only
    (warning,) = [w for w in ctx.report.warnings if "separate pieces" in w]
    assert "(100, 0, 0) - (102, 2, 2)" in warning and "1 debris piece" in warning
    # keep=all keeps every piece
    assert _repair_chain(surface, keep="all").surface.info().n_components == 3


def test_downstream_sees_only_the_kept_piece(tmp_path):
    from vmesh.chain import FilterChain

    surface, _ = HOSTILE_INPUTS["two_pieces"](tmp_path)
    ctx = FilterChain(["repair_surface", "cap_open_ends", "build_sdf"]).run(surface=surface)
    assert len(ctx.caps) == 2
    assert ctx.sdf.distance(np.array([[101.0, 1, 1]]))[0] < 0  # inside the dropped box: outside the vessel
    assert ctx.sdf.distance(np.array([[20.0, 0, 0]]))[0] > 0


def test_hole_in_the_wall_is_filled_open_ends_are_not(tmp_path):
    surface, _ = HOSTILE_INPUTS["hole_in_wall"](tmp_path)
    ctx = _repair_chain(surface)
    info = ctx.surface.info()
    assert info.n_boundary_loops == 2  # the two open ends stay for cap_open_ends
    (hole,) = ctx.report.sections["repair"]["filled_holes"]
    assert abs(hole["center"][0] - 20) < 1e-6 and hole["center"][1] > 2
    # the patch continues the wall: no new vertex far inside the tube (a flat patch dips to r = 2)
    new = ctx.surface.vertices[np.linalg.norm(ctx.surface.vertices[:, 1:], axis=1) < 2.999]
    assert len(new) and np.linalg.norm(new[:, 1:], axis=1).min() > 2.5
    assert any("filled 1 hole(s) in the wall" in w for w in ctx.report.warnings)
    assert _repair_chain(surface, fill_holes=False).surface.info().n_boundary_loops == 3


def test_open_tube_ends_cut_obliquely_are_not_holes():
    """Ends cut at up to 60° from the cross-section stay open ends."""
    from hostile_inputs import tube
    from vmesh import preprocess as pre

    v, f = tube()
    for angle in (0, 30, 60):
        w = v.copy()
        w[:, 0] += np.tan(np.radians(angle)) * w[:, 1] * (w[:, 0] > 20)  # shear the right half: an oblique end
        w[:, 0] -= np.tan(np.radians(angle)) * w[:, 1] * (w[:, 0] < 1e-9)
        assert pre.wall_hole_loops(w, f) == []


def test_degenerate_triangles_and_duplicated_vertices_are_repaired(tmp_path):
    for name in ("degenerate_triangles", "duplicated_vertices"):
        surface, _ = HOSTILE_INPUTS[name](tmp_path)
        ctx = _repair_chain(surface)
        info = ctx.surface.info()
        assert info.manifold and info.consistently_oriented and info.n_boundary_loops == 2 and info.n_components == 1


def test_fins_on_nonmanifold_edges_are_dropped():
    """A face hanging off a wall edge (three faces on one edge) is dropped; the tube stays
    a manifold with its two open ends."""
    from hostile_inputs import tube
    from vmesh import preprocess as pre

    v, f = tube()
    a, b = f[500, 0], f[500, 1]
    tip = (v[a] + v[b]) / 2 * [1, 1.5, 1.5]  # outside the wall
    v2 = np.vstack([v, tip])
    f2 = np.vstack([f, [[b, a, len(v)]], [[a, b, len(v)]]])  # a fin (two faces back to back)
    assert len(pre.nonmanifold_fins(v2, f2)) == 2
    out_v, out_f, _, report = pre.repair(v2, f2)
    assert report.duplicate_faces == 1 and report.nonmanifold_faces == 1 and report.nonmanifold_edges == 0
    assert len(out_f) == len(f) and len(out_v) == len(v)
    out_v, out_f, _, report = pre.repair(v2, f2[:-1])  # a single fin face
    assert report.nonmanifold_faces == 1 and len(out_f) == len(f)


def test_real_two_piece_tree_is_repaired(real_path):
    """hepatic_artery.stl: two pieces, a duplicate face and a face overlapping its
    neighbours on a non-manifold edge: the largest piece, closed and oriented."""
    from vmesh import preprocess as pre
    from vmesh.io.surface import read_surface

    s = read_surface(real_path("hepatic_artery.stl"))
    v, f, _, report = pre.repair(s.vertices, s.faces)
    assert report.nonmanifold_faces == 1 and len(report.filled_holes) == 1
    assert len(report.dropped_components) == 1 and report.dropped_components[0]["faces"] == 128
    from vmesh.surface import SurfaceMesh

    info = SurfaceMesh(v, f).info()
    assert info.closed and info.manifold and info.consistently_oriented and info.orientation == "outward"
