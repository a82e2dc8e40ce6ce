"""Surface readers/writers and diagnostics on every supported format."""

import numpy as np
import pytest

import vmesh
from vmesh.geometry import topology
from vmesh.io.surface import SURFACE_FORMATS


def cylinder():
    import pyvista as pv

    cyl = pv.Cylinder(direction=(0, 0, 1), radius=1.0, height=3.0, resolution=20, capping=True).triangulate().clean()
    return vmesh.SurfaceMesh(np.asarray(cyl.points), cyl.faces.reshape(-1, 4)[:, 1:], name="cyl")


@pytest.mark.parametrize("suffix", sorted(SURFACE_FORMATS))
def test_round_trip_every_format(tmp_path, suffix):
    s = cylinder()
    path = vmesh.write_surface(tmp_path / f"s{suffix}", s)
    r = vmesh.read_surface(path)
    info = r.info()
    assert r.n_faces == s.n_faces
    assert info.closed and info.manifold and info.consistently_oriented
    assert info.orientation == "outward"
    assert np.isclose(info.volume, s.info().volume, rtol=1e-5)


def test_mixed_polygons_are_triangulated(tmp_path):
    import pyvista as pv

    box = pv.Box(level=1)  # quads
    path = tmp_path / "box.vtp"
    box.save(path)
    s = vmesh.read_surface(path)
    assert s.faces.shape[1] == 3 and s.n_faces == 2 * box.n_cells
    assert s.info().closed


def test_open_surface_diagnostics():
    s = cylinder()
    # remove the caps: two open loops
    n = topology.face_normals(s.vertices, s.faces)
    side = np.abs(n[:, 2]) < 0.5
    open_s = s.copy(faces=s.faces[side])
    info = open_s.info()
    assert info.n_boundary_loops == 2 and not info.closed
    loops = topology.boundary_loops(open_s.faces)
    assert len(loops) == 2
    for loop in loops:  # each loop is one rim of the tube, in order
        z = open_s.vertices[loop, 2]
        assert np.ptp(z) < 1e-9 and len(loop) >= 10
        step = np.linalg.norm(np.diff(open_s.vertices[np.r_[loop, loop[:1]]], axis=0), axis=1)
        assert step.max() < 1.0


def test_inconsistent_orientation_detected():
    s = cylinder()
    f = s.faces.copy()
    f[0] = f[0, ::-1]
    assert not topology.is_consistently_oriented(f)
    assert s.copy(faces=f).info().orientation == "inconsistent"


def test_real_surfaces_load(real_path):
    for name, loops in [("carotid_vmtk.vtp", 0), ("coarctation_bpm120_open.stl", 5), ("aneurysm_ica_aneurisk_c0015_open.vtp", 3), ("thoracic_aorta_open.vtp", 6)]:
        info = vmesh.read_surface(real_path(name)).info()
        assert info.n_boundary_loops == loops, name
        assert info.manifold and info.n_components == 1
