"""Mends from the review of session 19's new-user changes: which folders an export may
replace (any MeshLab project, only OpenFOAM cases vmesh wrote, unreadable folders, a file
writer never), every export target checked before the first is written, numpy lengths,
batch ``--set`` checked without the rows, a PLY header read alone, the block faces the mesher records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vmesh.cli import main
from vmesh.errors import InputError
from vmesh.io.atomic import atomic_path, check_replaceable


def _one_hex():
    from test_export import unit_cube_mesh

    return unit_cube_mesh()


def test_a_meshlab_export_with_any_project_name_is_replaced(tmp_path):
    """``export_meshlab(project="x.mlp")`` wrote ``meshlab/x.mlp``; a later ``vmesh export
    --format meshlab`` looked for ``vmesh.mlp`` only and refused the folder."""
    from vmesh.io.meshlab import write_meshlab_folder

    folder = tmp_path / "meshlab"
    write_meshlab_folder(folder, _one_hex(), project="x.mlp")
    assert (folder / "x.mlp").is_file()
    check_replaceable(folder, folder=True)
    write_meshlab_folder(folder, _one_hex())
    assert sorted(p.name for p in folder.glob("*.mlp")) == ["vmesh.mlp"]


def test_only_an_openfoam_case_vmesh_wrote_is_replaced(tmp_path):
    """Any folder with ``constant/polyMesh`` was removed whole, a user's own case too."""
    from vmesh.io.openfoam import write

    case = tmp_path / "case"
    write(case, _one_hex())
    (case / "0").mkdir()  # a solver ran in it: still vmesh's case
    write(case, _one_hex())
    assert not (case / "0").exists() and (case / "constant" / "polyMesh" / "points").is_file()
    theirs = tmp_path / "theirs"
    (theirs / "constant" / "polyMesh").mkdir(parents=True)
    (theirs / "constant" / "polyMesh" / "points").write_text("FoamFile { object points; }\n8 ( )\n")
    with pytest.raises(InputError, match=r"theirs: is an OpenFOAM case vmesh did not write: not replaced"):
        write(theirs, _one_hex())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case", "theirs"]


def test_an_unreadable_folder_is_an_input_error(tmp_path, monkeypatch):
    """``iterdir`` outside the try: an unreadable folder gave a raw PermissionError."""
    folder = tmp_path / "locked"
    folder.mkdir()

    def denied(self):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(Path, "iterdir", denied)
    with pytest.raises(InputError, match=r"locked: cannot read this folder: Permission denied"):
        check_replaceable(folder, folder=True)


def test_a_file_writer_refuses_a_folder_in_its_place(tmp_path):
    """A folder named like the file (``mesh.msh/``) was refused as 'not an OpenFOAM case or
    MeshLab export', or, when empty, failed at the final rename with a raw OSError."""
    (tmp_path / "mesh.msh").mkdir()
    with pytest.raises(InputError, match=r"mesh\.msh: is a folder: not replaced by a file \(give a file name\)"):
        with atomic_path(tmp_path / "mesh.msh") as tmp:
            tmp.write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.msh"]


def test_every_export_target_is_checked_before_the_first_is_written(tmp_path, capsys):
    """``--format inp,openfoam`` with a folder of user files at RUN/openfoam wrote mesh.inp,
    then refused openfoam."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "mesh.vtu").write_text("")  # never read: the refusal comes first
    (run / "openfoam").mkdir()
    (run / "openfoam" / "notes.txt").write_text("keep me")
    assert main(["export", str(run), "--format", "inp,openfoam"]) == 2
    assert "openfoam: is a folder with other files (notes.txt)" in capsys.readouterr().err
    assert sorted(p.name for p in run.iterdir()) == ["mesh.vtu", "openfoam"]


def test_a_numpy_length_is_accepted(capsys):
    """``repr(np.float64(0.05))`` is 'np.float64(0.05)': a numpy length was refused."""
    from vmesh.registry import get_filter

    p = get_filter("mesh_transfinite").parameter("first_layer_height")
    assert p.validate(np.float64(0.05), "x") == "0.05" and p.validate(np.int64(2), "x") == "2"
    assert main(["filters", "mesh_transfinite"]) == 0
    assert "first_layer_height : length = '' (not set)" in capsys.readouterr().out


def test_batch_set_is_checked_without_the_rows(tmp_path):
    """The ``--set`` pre-check resolved the chain with ``--set`` alone: a parameter the rows
    supply (``meshlab_script.path``) refused the whole batch."""
    from vmesh.chain import FilterChain
    from vmesh.commands.batch import check_overrides

    chain_file = tmp_path / "c.toml"
    chain_file.write_text('[chain]\nname = "c"\n\n[[step]]\nfilter = "meshlab_script"\n')
    chain = FilterChain.load(str(chain_file))
    check_overrides(chain, {"meshlab_script.layer": "surface"})
    with pytest.raises(InputError, match=r"^--set: filter 'meshlab_script': parameter 'layer' = 'skin' is not one of"):
        check_overrides(chain, {"meshlab_script.layer": "skin"})


def test_a_ply_header_is_read_without_the_body(tmp_path, monkeypatch):
    """The edge-PLY hint read the whole file to parse its header."""
    from vmesh.io.surface import _ply_edge_count

    path = tmp_path / "edges.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                     b"element edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n" + b"0 0 0\n" * 20000)
    monkeypatch.setattr(Path, "read_bytes", lambda self: pytest.fail("whole file read"))
    assert _ply_edge_count(path) == 2


def test_block_faces_recorded_by_the_mesher_match_the_elements():
    """``StructuredMesh.boundary_local_face`` (recorded by ``connectivity``, which
    ``name_stub_faces`` reads) is the face each boundary face's element has it on
    (:func:`vmesh.io.export.boundary_local_faces`: an element's axes are its block's)."""
    from cylinder_blocks import cylinder_blocks, project_cylinder
    from vmesh.geometry.transfinite import Refinement, mesh_blocks
    from vmesh.io.export import boundary_local_faces
    from vmesh.mesh import HexMesh

    sm = mesh_blocks(cylinder_blocks(radius=2.0, sections=2), project_cylinder(2.0), Refinement(order=2))
    assert sm.boundary_local_face is not None
    recomputed = boundary_local_faces(HexMesh(points=sm.points, cells=sm.cells, order=sm.order,
                                              boundary_faces=sm.boundary_faces, boundary_cells=sm.boundary_cells))
    assert np.array_equal(recomputed, sm.boundary_local_face)
