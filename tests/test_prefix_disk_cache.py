"""The chain prefix kept on disk (vmesh.cache.DiskPrefixCache, `vmesh run`'s default): a
rerun on the same surface restores repair, caps, decimation and the signed distance with the
trees built over its surfaces, and meshes exactly as a run that computes them."""

from __future__ import annotations

import numpy as np
import pytest

import vmesh
from vmesh import cache as C
from vmesh.cli import main as vmesh_main
from vmesh.geometry import projection

from conftest import synthetic_case

SURFACE, SKELETON = synthetic_case("y_bifurcation")
PREFIX = ["repair_surface", "cap_open_ends", "decimate_surface", "build_sdf"]


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("VMESH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("VMESH_DISK_CACHE", raising=False)
    return tmp_path / "cache" / "prefix"


def _prefix_chain():
    chain = vmesh.FilterChain.load("default")
    names = [s.filter for s in chain.steps]
    chain.steps = chain.steps[: names.index("build_sdf") + 1]
    return chain


def test_a_rerun_restores_the_prefix_with_its_trees(cache_dir, monkeypatch):
    chain = _prefix_chain()
    first = chain.run(surface=SURFACE, cache=C.DiskPrefixCache())
    assert [s.filter for s in first.report.steps] == PREFIX and not any(s.cached for s in first.report.steps)
    assert len(list(cache_dir.glob("*.pkl"))) == 1
    cache = C.DiskPrefixCache()  # a new process: nothing in memory
    second = chain.run(surface=SURFACE, cache=cache)
    assert cache.hits == 1 and [s.filter for s in second.report.steps if s.cached] == PREFIX
    assert all(s.cpu_seconds == 0.0 for s in second.report.steps)
    for name in ("surface", "coarse_surface"):
        a, b = getattr(first, name), getattr(second, name)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert b.face_data.keys() == a.face_data.keys()
    for section in ("repair", "caps", "decimation", "sdf"):
        assert second.report.sections[section] == first.report.sections[section]
    assert second.report.warnings == first.report.warnings
    # the restored surface's tree is the signed distance's: not built again by later steps
    assert projection.surface_tree(second.surface) is second.sdf.fine._tree
    pts = np.random.default_rng(1).uniform(*first.sdf.bounds, size=(2000, 3))
    assert np.array_equal(first.sdf.distance(pts), second.sdf.distance(pts))
    # another surface, edited sources or caching off: the steps run
    moved = vmesh.SurfaceMesh(first.surface.vertices * 1.001, first.surface.faces)
    assert not any(s.cached for s in chain.run(surface=moved, cache=C.DiskPrefixCache()).report.steps)
    monkeypatch.setattr(C, "_DIGEST", ["an edited module"])
    assert not any(s.cached for s in chain.run(surface=SURFACE, cache=C.DiskPrefixCache()).report.steps)
    monkeypatch.setenv("VMESH_DISK_CACHE", "0")
    before = sorted(cache_dir.glob("*.pkl"))
    monkeypatch.setattr(C, "_DIGEST", ["another edit"])
    assert not any(s.cached for s in chain.run(surface=SURFACE, cache=C.DiskPrefixCache()).report.steps)
    assert sorted(cache_dir.glob("*.pkl")) == before


def test_a_damaged_entry_only_means_the_steps_run(cache_dir):
    chain = _prefix_chain()
    chain.run(surface=SURFACE, cache=C.DiskPrefixCache())
    (entry,) = cache_dir.glob("*.pkl")
    entry.write_bytes(entry.read_bytes()[:1000])
    ctx = chain.run(surface=SURFACE, cache=C.DiskPrefixCache())
    assert not any(s.cached for s in ctx.report.steps) and ctx.sdf is not None


def test_vmesh_run_twice_writes_the_same_mesh(cache_dir, tmp_path):
    cheap = ["--set", "mesh_transfinite.element_length=0.75", "--set", "compute_quality.histogram=''"]
    runs = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert vmesh_main(["run", "default", "-q", "-i", str(SURFACE), "-s", str(SKELETON), "-o", str(out), *cheap]) == 0
        runs.append(out)
    import json

    steps = [json.loads((out / "report.json").read_text())["steps"] for out in runs]
    assert not any(s.get("cached") for s in steps[0]) and [s["filter"] for s in steps[1] if s.get("cached")] == PREFIX
    assert (runs[0] / "mesh.vtu").read_bytes() == (runs[1] / "mesh.vtu").read_bytes()
    assert (runs[0] / "boundary.vtp").read_bytes() == (runs[1] / "boundary.vtp").read_bytes()
