"""A run-ready OpenFOAM case: boundary conditions, fluid, solver dictionaries; checkMesh on
synthetic cases; simpleFoam and pimpleFoam run it (tests skip where OpenFOAM is absent)."""

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from cfd_meshes import RADIUS, cylinder_mesh
from vmesh.cli import main
from vmesh.errors import ParameterError
from vmesh.io.export import convert_units, export_mesh
from vmesh.io.openfoam import patch_cells, read_field, read_polymesh
from vmesh.io.openfoam_case import BLOOD_NU, FlowCase

FOAM_DIR = "/usr/share/openfoam"


def foam(app, case, timeout=600):
    """Run an OpenFOAM application on ``case``; skip when OpenFOAM is not installed."""
    if shutil.which(app) is None:
        reason = f"OpenFOAM's {app} is not installed (apt-get install openfoam; .ci/run does)"
        print(f"SKIP: {reason}")
        pytest.skip(reason)
    env = dict(os.environ, WM_PROJECT_DIR=os.environ.get("WM_PROJECT_DIR", FOAM_DIR))
    r = subprocess.run([app, "-case", str(case)], capture_output=True, text=True, env=env, timeout=timeout)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return r.stdout


def residuals(log: str, field: str) -> np.ndarray:
    """Initial residuals of ``field`` (first solve of each iteration/time step)."""
    return np.array([float(v) for v in re.findall(rf"Solving for {field}, Initial residual = ([-+0-9.eE]+)", log)])


@pytest.fixture(scope="module")
def tube():
    """A 40 mm long cylinder of radius 2 mm in metres, graded boundary layer."""
    mesh, _ = cylinder_mesh(sections=9, length=40.0, first_layer_height="0.05mm")
    return convert_units(mesh, "m")


def test_case_files(tube, tmp_path):
    case = export_mesh(tmp_path / "c", tube, "openfoam", flow=FlowCase("steady", inlet_velocity=0.02))
    U = (case / "0" / "U").read_text()
    assert re.search(r"inlet\s*\{\s*type\s+surfaceNormalFixedValue;\s*refValue\s+uniform -0.02;", U)
    assert re.search(r"wall\s*\{\s*type\s+noSlip;", U) and re.search(r"outlet_1\s*\{\s*type\s+zeroGradient;", U)
    p = (case / "0" / "p").read_text()
    assert re.search(r"outlet_1\s*\{\s*type\s+fixedValue;\s*value\s+uniform 0;", p)
    assert re.search(r"inlet\s*\{\s*type\s+zeroGradient;", p) and "[0 2 -2 0 0 0 0]" in p
    assert f"nu              [0 2 -1 0 0 0 0] {BLOOD_NU:.9g};" in (case / "constant" / "transportProperties").read_text()
    assert "application     simpleFoam;" in (case / "system" / "controlDict").read_text()
    assert "lengths in m" in (case / "system" / "controlDict").read_text()
    transient = export_mesh(tmp_path / "t", tube, "openfoam", flow=FlowCase("transient"))
    assert "application     pimpleFoam;" in (transient / "system" / "controlDict").read_text()
    assert "PIMPLE" in (transient / "system" / "fvSolution").read_text()


def test_case_needs_metres(tmp_path):
    mesh, _ = cylinder_mesh()
    with pytest.raises(ParameterError, match="needs lengths in metres, the mesh is in mm .export with --to-units m.") as e:
        export_mesh(tmp_path / "c", mesh, "openfoam", flow=FlowCase())
    assert "\n" not in str(e.value) and not (tmp_path / "c").exists()


def test_checkmesh_ok_on_synthetic_cases(tube, tmp_path):
    out = foam("checkMesh", export_mesh(tmp_path / "mesh_only", tube, "openfoam"))
    assert "Mesh OK." in out
    out = foam("checkMesh", export_mesh(tmp_path / "steady", tube, "openfoam", flow=FlowCase("steady")))
    assert "Mesh OK." in out
    assert re.search(r"vessel\s+%d\s" % tube.n_cells, out)  # the cellZone, every cell


def test_simplefoam_poiseuille(tube, tmp_path):
    """Laminar pipe flow: residuals fall below 1e-3 and the pressure drop is Poiseuille's
    (8 nu L U / R^2 between the inlet and the outlet) within the coarse mesh's error."""
    u, length, radius = 0.01, 0.04, RADIUS * 1e-3
    case = export_mesh(tmp_path / "pipe", tube, "openfoam", flow=FlowCase("steady", inlet_velocity=u, iterations=400))
    log = foam("simpleFoam", case)
    res = residuals(log, "p")
    assert len(res) and res.min() < 1e-3 and np.isfinite(res).all()
    last = max(int(d.name) for d in case.iterdir() if d.name.isdigit())
    p = read_field(case, last, "p")
    poly = read_polymesh(case)
    drop = p[patch_cells(poly, "inlet")].mean() - p[patch_cells(poly, "outlet_1")].mean()
    expected = 8 * BLOOD_NU * length * u / radius**2
    assert 0.7 * expected < drop < 1.5 * expected, (drop, expected)


def test_pimplefoam_runs(tube, tmp_path):
    case = export_mesh(tmp_path / "pulse", tube, "openfoam", flow=FlowCase("transient", inlet_velocity=0.01, end_time=0.02, time_step=1e-3))
    log = foam("pimpleFoam", case)
    assert "End" in log and np.isfinite(residuals(log, "p")).all()
    assert (case / "0.02" / "U").is_file()


@pytest.mark.slow
def test_simplefoam_y_bifurcation(y_run, tmp_path, capsys):
    """The Y-bifurcation exported as a steady case converges with a plausible pressure drop."""
    case = tmp_path / "y"
    assert main(["export", str(y_run), "--format", "openfoam", "--case", "steady", "--to-units", "m",
                 "--inlet-velocity", "0.05", "--iterations", "300", "-o", str(case)]) == 0
    assert "Mesh OK." in foam("checkMesh", case)
    log = foam("simpleFoam", case)
    res = residuals(log, "p")
    assert res[-1] < 1e-3 and residuals(log, "Ux")[-1] < 1e-3
    last = max(int(d.name) for d in case.iterdir() if d.name.isdigit())
    p, U = read_field(case, last, "p"), read_field(case, last, "U")
    poly = read_polymesh(case)
    drop = p[patch_cells(poly, "inlet")].mean() - min(p[patch_cells(poly, n)].mean() for n in poly["patches"] if n.startswith("outlet"))
    # Poiseuille through the inlet branch's radius over the inlet-outlet distance, as an order of magnitude
    pts = poly["points"]
    faces = poly["faces"]
    centre = {n: pts[faces[v["startFace"]: v["startFace"] + v["nFaces"]]].mean(axis=(0, 1)) for n, v in poly["patches"].items()}
    radius = np.sqrt(sum(np.linalg.norm(np.cross(*(pts[f][[2, 3]] - pts[f][[0, 1]])), axis=-1) / 2 for f in
                         faces[poly["patches"]["inlet"]["startFace"]: poly["patches"]["inlet"]["startFace"] + poly["patches"]["inlet"]["nFaces"]]) / np.pi)
    length = np.linalg.norm(centre["outlet_1"] - centre["inlet"])
    estimate = 8 * BLOOD_NU * length * 0.05 / radius**2
    assert 0.3 * estimate < drop < 5 * estimate, (drop, estimate)
    assert np.linalg.norm(U, axis=1).max() < 10 * 0.05  # no runaway velocities


def test_cli_case_errors_write_nothing(y_run, tmp_path, capsys):
    before = sorted(p.name for p in y_run.iterdir())
    assert main(["export", str(y_run), "--format", "msh,openfoam", "--case", "steady", "-q"]) == 2
    err = capsys.readouterr().err
    assert err == f"vmesh: error: {y_run}: an OpenFOAM steady case needs lengths in metres, the mesh is in mm: add --to-units m\n"
    assert main(["export", str(y_run), "--format", "msh", "--case", "steady", "--to-units", "m"]) == 2
    assert "--case writes an OpenFOAM case: add --format openfoam" in capsys.readouterr().err
    assert main(["export", str(y_run), "--format", "openfoam", "--case", "steady", "--to-units", "m", "--inlet-velocity", "-1"]) == 2
    assert "--inlet-velocity -1.0 must be positive" in capsys.readouterr().err
    # a flow-case option without --case would do nothing: refused, not ignored
    assert main(["export", str(y_run), "--format", "msh", "--iterations", "50"]) == 2
    assert "--iterations set(s) up an OpenFOAM flow case: add --case steady|transient --format openfoam" in capsys.readouterr().err
    assert sorted(p.name for p in y_run.iterdir()) == before
