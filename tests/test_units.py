"""Length units: guessed or given for the input, stated in report.json, the summary and every
output; converted on export (--to-units, --scale)."""

import json

import numpy as np
import pytest

from cfd_meshes import cylinder_mesh
from conftest import synthetic_case
from vmesh.cli import main
from vmesh.errors import ParameterError
from vmesh.geometry.boundary_layer import guess_units, resolve_units
from vmesh.io.export import convert_units, export_mesh


def test_guess_units():
    assert guess_units(0.15) == "m"  # a 15 cm aorta in metres
    assert guess_units(1.9) == "m"
    assert guess_units(12.0) == "mm"  # a small aneurysm in mm
    assert guess_units(150.0) == "mm"


def test_a_doubtful_unit_guess_is_said_once():
    """Session 22: kd_lima (cm, PROVENANCE) was meshed as mm without a word; a guessed unit
    other than mm says why, and mm guessed for a model small for mm vessels says so; never
    a failure, once per run, nothing when --units is given or the model is mm-sized."""
    from vmesh.context import Context
    from vmesh.skeleton import Skeleton
    from vmesh.surface import SurfaceMesh

    def ctx_for(scale, radius, units=None):
        ctx = Context(inputs={"units": units} if units else {})
        box = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale
        ctx.surface = SurfaceMesh(box, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
        ctx.skeleton = Skeleton(box[:2], np.full(2, radius), np.array([[0, 1]]))
        return ctx

    lima = ctx_for(6.2, 0.106)  # kd_lima's size: diagonal 10.7, median radius 0.106
    assert resolve_units(lima)["length"] == "mm" and resolve_units(lima)["length"] == "mm"
    assert len(lima.report.warnings) == 1 and "median vessel radius 0.106" in lima.report.warnings[0]
    assert "give --units cm" in lima.report.warnings[0]
    tiny = ctx_for(0.05, 0.002)
    assert resolve_units(tiny)["length"] == "m" and "length unit m assumed: the surface's bounding-box diagonal 0.0866" in tiny.report.warnings[0]
    for quiet in (ctx_for(30.0, 0.42), ctx_for(6.2, 0.106, units="cm")):  # BraVa's median radius; a unit given
        resolve_units(quiet)
        assert quiet.report.warnings == []


def test_run_states_guessed_units(y_run):
    report = json.loads((y_run / "report.json").read_text())
    assert report["units"]["length"] == "mm" and report["units"]["source"].startswith("guessed from the bounding-box diagonal")
    assert any(step["counts"].get("units") == "mm" for step in report["steps"])  # the summary table


def test_run_units_option_and_every_output(tmp_path, capsys):
    surface, skeleton = synthetic_case("straight_tube")
    out = tmp_path / "run"
    assert main(["run", "default", "-i", str(surface), "-s", str(skeleton), "-o", str(out), "--units", "cm",
                 "--set", "mesh_transfinite.first_layer_height=0.1mm", "--set", "mesh_transfinite.boundary_layer_thickness=2mm",
                 "--set", "mesh_transfinite.elements_layer=5"]) == 0
    assert "units=cm" in capsys.readouterr().out  # the log's summary table
    report = json.loads((out / "report.json").read_text())
    assert report["units"] == {"length": "cm", "source": "given (--units)", "metres_per_unit": 0.01}
    assert report["inputs"]["units"] == "cm"
    layer = report["boundary_layer"]
    assert (layer["first_height"], layer["thickness"], layer["elements"]) == ("0.01 cm", "0.2 cm", 5)
    assert abs(layer["measured_first_height"]["median"] / 0.01 - 1) < 0.05
    assert layer["measured_first_edge"]["within_5_percent"] > 0.95
    # along the wall normal, at every wall node (docs/cfd.md): exact by construction
    assert layer["measured_first_node_height"]["within_5_percent"] == 1.0
    assert abs(layer["measured_first_node_height"]["min"] / 0.01 - 1) < 1e-6 and layer["offset"]["kept"] == 0
    assert main(["export", str(out), "--format", "msh,inp,exo,mesh,xdmf", "-q"]) == 0
    assert "$Units\ncm\n" in (out / "mesh.msh").read_text()[:100]
    assert "** units: cm" in (out / "mesh.inp").read_text()[:300]
    assert "# units: cm" in (out / "mesh.mesh").read_text()[:100]
    assert '"units": "cm"' in (out / "mesh.xdmf").read_text()
    import netCDF4

    with netCDF4.Dataset(out / "mesh.exo") as nc:
        assert nc.units == "cm"
    # vtu rewritten in metres records it, and a later export converts from it, not from report.json
    assert main(["export", str(out), "--format", "vtu", "--to-units", "m", "-q"]) == 0
    assert main(["export", str(out), "--format", "msh", "--to-units", "m", "-q"]) == 0
    assert "$Units\nm\n" in (out / "mesh.msh").read_text()[:100]
    with pytest.raises(SystemExit) as e:
        main(["run", "default", "-i", str(surface), "-o", str(tmp_path / "x"), "--units", "inch"])
    assert e.value.code == 2 and "invalid choice: 'inch'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_convert_units():
    mesh, _ = cylinder_mesh()
    m = convert_units(mesh, "m")
    assert m.units == "m" and np.allclose(m.points, mesh.points * 1e-3)
    assert convert_units(mesh, "mm") is mesh
    s = convert_units(mesh, scale=10.0)
    assert s.units is None and np.allclose(s.points, mesh.points * 10)
    with pytest.raises(ParameterError, match="must be positive"):
        convert_units(mesh, scale=0.0)
    mesh.units = None
    with pytest.raises(ParameterError, match="does not record its length unit"):
        convert_units(mesh, "m")


def test_every_format_records_units(tmp_path):
    import meshio

    from vmesh.io.mesh import units_from_field_data

    mesh, _ = cylinder_mesh()
    m = convert_units(mesh, "m")
    assert units_from_field_data(meshio.read(export_mesh(tmp_path / "a.vtu", m)).field_data) == "m"
    foam = export_mesh(tmp_path / "foam", m, "openfoam")
    assert "lengths in m" in (foam / "constant" / "polyMesh" / "points").read_text()[:800]
