"""Disk cache of deterministic steps (vmesh.disk_cache): keys follow every input byte and
option, a hit gives back the same arrays, and the decimation reads its result back."""

from __future__ import annotations

import os

import numpy as np
import pytest

from vmesh import disk_cache
from vmesh.chain import FilterChain
from vmesh.surface import SurfaceMesh


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("VMESH_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("VMESH_DISK_CACHE", raising=False)
    return tmp_path


def test_key_follows_bytes_dtype_shape_and_options():
    a = np.arange(12, dtype=np.float64).reshape(4, 3)
    k = disk_cache.key("x", a, 3, [("b", True)])
    assert k == disk_cache.key("x", a.copy(), 3, [("b", True)])
    b = a.copy()
    b[2, 1] = np.nextafter(b[2, 1], np.inf)  # one ulp
    others = [
        disk_cache.key("x", b, 3, [("b", True)]),
        disk_cache.key("x", a.astype(np.float32), 3, [("b", True)]),
        disk_cache.key("x", a.reshape(3, 4), 3, [("b", True)]),
        disk_cache.key("x", a, 4, [("b", True)]),
        disk_cache.key("x", a, 3, [("b", False)]),
    ]
    assert len({k, *others}) == 6


def test_store_load_prune_and_off(cache_dir, monkeypatch):
    arrays = {"v": np.random.default_rng(0).normal(size=(5, 3)), "f": np.arange(6, dtype=np.int64).reshape(2, 3)}
    assert disk_cache.load("t", "abc") is None
    assert disk_cache.store("t", "abc", arrays)
    back = disk_cache.load("t", "abc")
    assert back.keys() == arrays.keys()
    for name in arrays:
        assert back[name].dtype == arrays[name].dtype and np.array_equal(back[name], arrays[name])
    for i in range(5):
        disk_cache.store("t", f"k{i}", arrays)
        os.utime(cache_dir / "t" / f"k{i}.npz", (1000 + i, 1000 + i))
    disk_cache.prune("t", keep=2)
    assert sorted(p.stem for p in (cache_dir / "t").glob("*.npz")) == ["abc", "k4"]  # abc: written now
    (cache_dir / "t" / "broken.npz").write_bytes(b"PK\x03\x04 truncated")
    assert disk_cache.load("t", "broken") is None  # a damaged entry only means the step runs
    monkeypatch.setenv("VMESH_DISK_CACHE", "0")
    assert disk_cache.load("t", "k4") is None and not disk_cache.store("t", "new", arrays)


def _sphere(level=5):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.create_sphere(radius=2.0, subdiv=level)
    m = ms.current_mesh()
    return SurfaceMesh(m.vertex_matrix().astype(float), m.face_matrix().astype(np.int64))


def test_decimation_read_back_is_identical(cache_dir):
    """The second decimation of the same surface comes from the cache with the same coarse
    surface and deviation; another target or surface decimates anew."""
    surface = _sphere()  # 20,480 triangles
    chain = FilterChain([("decimate_surface", {"target_faces": 2000})])
    first = chain.run(surface=surface)
    second = chain.run(surface=surface)
    assert "cached" not in first.report.steps[0].counts and second.report.steps[0].counts["cached"] is True
    assert np.array_equal(first.coarse_surface.vertices, second.coarse_surface.vertices)
    assert np.array_equal(first.coarse_surface.faces, second.coarse_surface.faces)
    assert first.report.sections["decimation"] == second.report.sections["decimation"]
    other = FilterChain([("decimate_surface", {"target_faces": 2100})]).run(surface=surface)
    assert "cached" not in other.report.steps[0].counts and other.coarse_surface.n_faces != 2000
    moved = SurfaceMesh(surface.vertices * 1.001, surface.faces)
    assert "cached" not in chain.run(surface=moved).report.steps[0].counts
    assert len(list((cache_dir / "decimated").glob("*.npz"))) == 3
