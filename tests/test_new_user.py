"""What a new user trips over (docs/inputs_and_failures.md, session 18 walkthrough): a
chain file's unknown parameter, an output folder that cannot be written, objects printed
at the prompt. Each error is one line naming the file and the problem, exit status 2,
nothing written."""

from __future__ import annotations

import numpy as np
import pytest

from hostile_inputs import _write_ply, tube
from vmesh.chain import FilterChain
from vmesh.cli import main
from vmesh.context import Context
from vmesh.errors import InputError, ParameterError
from vmesh.io.atomic import atomic_path
from vmesh.mesh import HexMesh
from vmesh.registry import get_filter
from vmesh.surface import SurfaceMesh

CHAIN_WITH_A_WRONG_NAME = """
[[step]]
filter = "repair_surface"

[[step]]
filter = "export_mesh"
[step.params]
path = "mesh.msh"
"""


def test_a_chain_files_unknown_parameter_names_the_file_and_the_step(tmp_path):
    """It used to surface at run time as 'step 2: filter ... has no parameter' with no
    file named and no list of what the filter takes."""
    path = tmp_path / "my_chain.toml"
    path.write_text(CHAIN_WITH_A_WRONG_NAME)
    with pytest.raises(InputError) as err:
        FilterChain.load(path)
    message = str(err.value)
    assert message.startswith(f"{path}: step 2: filter 'export_mesh' has no parameter 'path'")
    assert "its parameters: filename, format, linearize" in message


def test_an_unknown_parameter_is_refused_when_the_step_is_added():
    with pytest.raises(ParameterError, match=r"no parameter 'target_face' \(did you mean 'target_faces'\?\)"):
        FilterChain(["repair_surface"]).append("decimate_surface", target_face=1000)
    with pytest.raises(ParameterError, match=r"\(its parameters: "):
        get_filter("build_sdf").parameter("zzz")


def test_an_output_folder_that_cannot_be_created_is_one_line_and_nothing_is_written(tmp_path, monkeypatch, capsys):
    """A read-only or virtual file system (/proc, /sys; even root cannot write there) used
    to stop the run as an internal error ('a bug in vmesh')."""
    import vmesh.chain

    surface = _write_ply(tmp_path / "tube.ply", *tube(n_around=12, n_along=8))

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(vmesh.chain.tempfile, "mkdtemp", refuse)
    out = tmp_path / "out"
    code = main(["run", "default", "-q", "-i", str(surface), "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == f"vmesh: error: {out}: cannot create the output folder: Permission denied"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tube.ply"]


def test_a_file_that_cannot_be_written_is_an_input_error(tmp_path):
    (tmp_path / "a_file").write_text("")
    target = tmp_path / "a_file" / "mesh.msh"
    with pytest.raises(InputError, match=r"mesh\.msh: cannot write here: "):
        with atomic_path(target):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_layers_print_as_one_line_of_counts():
    """Printing the context of a run (or its mesh) at the prompt used to dump every array."""
    v, f = tube(n_around=12, n_along=8)
    surface = SurfaceMesh(v, f, name="tube.ply")
    cube = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    mesh = HexMesh(cube, np.arange(8)[None], units="mm", label_names={0: "vessel"})
    ctx = Context(surface=surface, mesh=mesh, quality={"summary": {"min": 1.0, "mean": 1.0, "n_invalid": 0}})
    assert repr(surface) == f"SurfaceMesh('tube.ply': {len(v)} vertices, {len(f)} triangles)"
    assert repr(mesh) == "HexMesh(1 hexahedra of order 1, 8 nodes, units mm, labels ['vessel'], boundaries ['wall'])"
    text = repr(ctx)
    assert "\n" not in text and "array" not in text
    assert text.startswith("Context(surface=SurfaceMesh('tube.ply'") and "quality={'min': 1.0, 'mean': 1.0, 'n_invalid': 0}" in text


def test_a_set_value_given_after_a_space_is_explained(capsys):
    """``--set a.b 3`` (a space where ``=`` belongs): the error shows the one-word form."""
    with pytest.raises(SystemExit) as exc:
        main(["run", "default", "--set", "mesh_transfinite.refinement", "2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--set mesh_transfinite.refinement=2" in err


def test_a_chain_files_params_that_are_not_a_table_are_refused(tmp_path):
    """``params = 3`` in a chain file: one input error naming the file and step, not a TypeError."""
    p = tmp_path / "bad.toml"
    p.write_text('[chain]\nname = "bad"\n\n[[step]]\nfilter = "repair_surface"\nparams = 3\n')
    with pytest.raises(InputError, match=r"bad\.toml.*step 1 \(repair_surface\): params must be a table"):
        FilterChain.load(str(p))


@pytest.mark.parametrize("value", ["0.05mmm", "-1mm", "0mm", "5 furlongs"])
def test_a_bad_length_is_refused_when_the_step_is_added(value):
    """``--set mesh_transfinite.first_layer_height=0.05mmm`` used to run nine steps and stop
    in ``mesh_transfinite`` with an ``OUT.failed/``; a length is now checked with the other
    values, before the first step (``FilterChain.resolved``, as ``run`` does)."""
    with pytest.raises(ParameterError, match=r"first_layer_height' = .*expected a positive length such as 0\.05mm"):
        FilterChain.load("default").with_overrides({"mesh_transfinite.first_layer_height": value}).resolved()


def test_a_length_without_a_unit_may_be_a_plain_number():
    """'no unit = the input's units': ``--set ...first_layer_height=0.05`` (a TOML float)
    used to be refused as 'must be of type str'."""
    p = get_filter("mesh_transfinite").parameter("first_layer_height")
    assert p.validate(0.05, "x") == "0.05" and p.validate(2, "x") == "2"
    assert p.validate("50um", "x") == "50um" and p.validate("", "x") == ""
    with pytest.raises(ParameterError, match="must be of type length"):
        p.validate(True, "x")


CENTERLINE_FILES = {
    "centerline.vtk": "# vtk DataFile Version 3.0\nline\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0 2 0 0\nLINES 1 4\n3 0 1 2\n",
    "centerline.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0\n1 0 0\n2 0 0\n0 1\n1 2\n",
}


@pytest.mark.parametrize("name", sorted(CENTERLINE_FILES))
def test_a_centerline_given_as_the_surface_is_named_as_such(tmp_path, name):
    """``-i centerline.vtp`` said 'no surface faces found (empty or corrupt ... file)',
    as for a broken file; it now says the file holds lines and where a centerline goes."""
    from vmesh.io.surface import read_surface

    path = tmp_path / name
    path.write_text(CENTERLINE_FILES[name])
    with pytest.raises(InputError, match=r"no surface faces, only \d+ (line cell|edge)\(s\): is it a centerline .* --skeleton"):
        read_surface(path)


def test_a_folder_export_does_not_replace_a_folder_of_other_files(tmp_path):
    """``vmesh export RUN -f openfoam -o DIR`` removed DIR with whatever it held; a folder
    writer now replaces only an empty folder or one it wrote (an OpenFOAM case, a MeshLab
    export), and refuses the rest before writing."""
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("keep me")
    with pytest.raises(InputError, match=r"notes: is a folder with other files \(todo\.txt\).*not replaced"):
        with atomic_path(notes, folder=True):
            pass
    assert (notes / "todo.txt").read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["notes"]
    case = tmp_path / "case"
    (case / "constant" / "polyMesh").mkdir(parents=True)
    (case / "constant" / "polyMesh" / "boundary").write_text("/*---*\\\n  Written by vmesh 0.1\n*/\n")
    with atomic_path(case, folder=True) as tmp:
        tmp.unlink()
        (tmp / "system").mkdir(parents=True)
    assert sorted(p.name for p in case.iterdir()) == ["system"]


def test_vmesh_info_diagnoses_every_file_and_fails_at_the_end(tmp_path, capsys):
    """``vmesh info bad.stl good.ply`` stopped at the first bad file; a diagnosis now
    covers every file, one error line for each bad one, and exits 2."""
    v, f = tube(n_around=8, n_along=4)
    good = _write_ply(tmp_path / "good.ply", v, f)
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    assert main(["info", str(empty), str(good), str(tmp_path / "missing.stl")]) == 2
    out, err = capsys.readouterr()
    assert out.startswith(f"{good}\n") and "triangles" in out
    assert err.splitlines() == [f"vmesh: error: {empty}: file is empty", f"vmesh: error: {tmp_path / 'missing.stl'}: file not found"]


def test_an_override_value_is_checked_when_given():
    """Session 20: ``with_overrides({"mesh_transfinite.refinement": "two"})`` was taken and
    refused only by ``run``; the value is now checked against its parameter at once, and
    "auto" still resets an automatic parameter."""
    chain = FilterChain.load("default")
    with pytest.raises(ParameterError, match=r"filter 'mesh_transfinite': parameter 'refinement' must be of type int, got str 'two'"):
        chain.with_overrides({"mesh_transfinite.refinement": "two"})
    with pytest.raises(ParameterError, match="below its minimum"):
        chain.with_overrides({"mesh_transfinite.refinement": 0})
    chain.with_overrides({"decimate_surface.target_faces": "auto", "mesh_transfinite.refinement": 2})


def test_render_pictures_takes_the_chains_block_structure():
    """Session 20: ``render_pictures(..., blocks=ctx.blocks)`` stopped on
    ``'BlockStructure' object has no attribute 'n_cells'``: it wanted ``blocks.vtu`` read
    with pyvista. A BlockStructure is now drawn from its own grid (same cells and arrays)."""
    from cylinder_blocks import cylinder_blocks
    from vmesh.render import _blocks_grid

    blocks = cylinder_blocks()
    grid = _blocks_grid(blocks)
    assert grid.n_cells == blocks.n_blocks and "segment_id" in grid.cell_data
    assert _blocks_grid(grid) is grid and _blocks_grid(None) is None


def test_vmesh_skeleton_names_the_option_a_bad_value_came_from(tmp_path, capsys):
    """Session 20: ``vmesh skeleton --spacing -1`` said ``step 2: filter
    'resample_skeleton': parameter 'spacing' ...`` (the chain the command builds); it now
    names ``--spacing``, exit status 2, nothing written."""
    from pathlib import Path

    skeleton = Path(__file__).resolve().parents[1] / "data_synthetic" / "y_bifurcation" / "skeleton.json"
    out = tmp_path / "s.swc"
    assert main(["skeleton", str(skeleton), "-o", str(out), "--no-png", "--spacing", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vmesh: error: --spacing -1: filter 'resample_skeleton': parameter 'spacing'"), err
    assert not out.exists()


def test_set_on_a_filter_the_chain_lacks_says_how_to_add_it():
    """Session 21: `--set tag_skeleton.branches=true` on `default` suggested 'extract_skeleton';
    a registered filter the chain lacks now says to add a step, a misspelt one is matched
    against every filter."""
    chain = FilterChain.load("default")
    with pytest.raises(ParameterError, match=r"add a \[\[step\]\] filter = \"tag_skeleton\"") as exc:
        chain.with_overrides({"tag_skeleton.branches": True})
    assert "did you mean" not in str(exc.value)
    with pytest.raises(ParameterError, match="did you mean 'tag_skeleton'"):
        chain.with_overrides({"tag_skeletn.branches": True})


def test_a_truncated_binary_ply_is_one_line_not_a_crash(tmp_path):
    """Session 21: a binary PLY cut short went on to VTK's reader, which ended the process
    (a segmentation fault; on Dask, every worker that took the row died)."""
    from vmesh.io.surface import _write_ply_triangles, read_surface

    v, f = tube()
    whole = tmp_path / "whole.ply"
    _write_ply_triangles(whole, v, f)
    cut = tmp_path / "cut.ply"
    cut.write_bytes(whole.read_bytes()[:2000])
    with pytest.raises(InputError, match=r"cut\.ply: the file ends early: 2000 bytes.*truncated"):
        read_surface(cut)
    assert len(read_surface(whole).faces) == len(f)
    # a layout the numpy reader hands to VTK (a face colour) is checked before that hand-over
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty float x\n"
              f"property float y\nproperty float z\nelement face {len(f)}\n"
              "property list uchar int vertex_indices\nproperty uchar red\nend_header\n").encode()
    faces = np.zeros(len(f), [("k", "u1"), ("v", "<i4", (3,)), ("red", "u1")])
    faces["k"], faces["v"] = 3, f
    coloured = header + v.astype("<f4").tobytes() + faces.tobytes()
    cut.write_bytes(coloured[:2000])
    with pytest.raises(InputError, match=r"cut\.ply: the file ends early: 2000 bytes"):
        read_surface(cut)


def test_an_off_file_with_normals_as_pymeshlab_writes_it(tmp_path):
    """Session 21: pymeshlab saves `NOFF` (vertex normals); meshio reads plain `OFF` only and
    ended vmesh with SystemExit (exit status 1, meshio's own two lines)."""
    from vmesh.io.surface import read_surface

    v, f = tube(n_around=8, n_along=4)
    normals = v * 0 + [0.0, 0.0, 1.0]
    rows = [" ".join(map(str, list(p) + list(n))) for p, n in zip(v, normals)]
    text = "NOFF\n# a comment\n%d %d 0\n%s\n%s\n" % (len(v), len(f), "\n".join(rows), "\n".join("3 %d %d %d" % tuple(t) for t in f))
    (tmp_path / "n.off").write_text(text)
    s = read_surface(tmp_path / "n.off")
    assert s.faces.shape == f.shape and np.allclose(s.vertices, v)
    (tmp_path / "cut.off").write_text(text[: len(text) // 2])
    with pytest.raises(InputError, match="cut.off: could not read as OFF: the file ends early"):
        read_surface(tmp_path / "cut.off")
    (tmp_path / "bad.off").write_text("hello\n1 2\n")
    with pytest.raises(InputError, match="not an OFF keyword"):
        read_surface(tmp_path / "bad.off")
    (tmp_path / "bin.off").write_bytes(b"OFF BINARY\n\x00\x00\x00\x08")
    with pytest.raises(InputError, match="binary OFF is not read"):
        read_surface(tmp_path / "bin.off")
