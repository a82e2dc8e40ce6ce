"""What ``decimate_surface`` prepares while pymeshlab decimates (``vmesh/preload.py``): the
later steps' modules and the fine surface's signed distance, with the results of the
steps unchanged."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from vmesh import preload
from vmesh.chain import FilterChain
from vmesh.geometry import projection
from vmesh.geometry.sdf import SignedDistance
from vmesh.surface import SurfaceMesh


def _sphere(level=5) -> SurfaceMesh:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.create_sphere(radius=2.0, subdiv=level)  # 20,480 triangles
    m = ms.current_mesh()
    return SurfaceMesh(m.vertex_matrix().astype(float), m.face_matrix().astype(np.int64))


def test_lazy_imports_follow_the_filters_own_helpers():
    from vmesh.registry import get_filter

    f = get_filter("mesh_transfinite").function
    found = preload.lazy_imports(f.__module__, f.__name__)
    # mesh_transfinite itself imports the mesher; the optimiser only inside its helper _light_pass
    assert {"vmesh.geometry.transfinite", "vmesh.geometry.optimize"} <= set(found)
    assert all(m.startswith("vmesh.") for m in found) and len(found) == len(set(found))
    f = get_filter("label_elements").function
    assert "vmesh.geometry.optimize" not in preload.lazy_imports(f.__module__, f.__name__)


def test_import_later_steps_imports_what_the_later_steps_import():
    """In a fresh interpreter: nothing outside a chain; the block builder's modules for a later
    build_block_structure; an unknown filter is skipped."""
    code = (
        "import sys\n"
        "from vmesh import preload\n"
        "from vmesh.chain import Step\n"
        "assert preload.import_later_steps() == []\n"
        "assert 'vmesh.geometry.blocks.builder' not in sys.modules\n"
        "preload.LATER_STEPS.set((Step('no_such_filter'), Step('build_block_structure')))\n"
        "done = preload.import_later_steps()\n"
        "assert 'vmesh.geometry.block_builder' in done, done\n"
        "assert 'vmesh.geometry.blocks.builder' in sys.modules\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ))
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_fine_distance_built_during_decimation_is_the_one_build_sdf_uses(monkeypatch):
    """With pymeshlab in its thread (no decimation on disk), the fine surface's signed
    distance is built once, in the decimation's wait, and build_sdf's two-step distance
    refines on that object; its distances equal a fresh ``SignedDistance.from_surface``'s
    bit for bit, as do the coarse surface and the two-step distances of a chain whose
    decimation prepared nothing."""
    monkeypatch.setenv("VMESH_DISK_CACHE", "0")
    built, preparing = [], []
    original = SignedDistance.from_surface.__func__
    real_prepare = preload.prepare_surface

    def prepare(surface):  # marks the distances built in the decimation's wait
        preparing.append(True)
        try:
            return real_prepare(surface)
        finally:
            preparing.pop()

    def counting(cls, surface, sign="auto"):
        built.append((bool(preparing), surface.n_faces))
        return original(cls, surface, sign)

    monkeypatch.setattr(preload, "prepare_surface", prepare)

    monkeypatch.setattr(SignedDistance, "from_surface", classmethod(counting))
    steps = [("decimate_surface", {"target_faces": 2000}), ("build_sdf", {"source": "coarse", "refine_on_fine": True})]
    surface = _sphere()
    ctx = FilterChain(steps).run(surface=surface)
    # the fine one once, in the decimation's wait; build_sdf builds only the coarse one
    assert built == [(True, 20480), (False, ctx.coarse_surface.n_faces)]
    assert ctx.sdf.fine is projection.surface_distance(ctx.surface)

    # the same chain, its decimation preparing nothing: same coarse surface, same distances
    monkeypatch.setattr(preload, "import_later_steps", lambda: [])
    monkeypatch.setattr(preload, "prepare_surface", lambda surface: [])
    plain = FilterChain(steps).run(surface=_sphere())
    assert np.array_equal(plain.coarse_surface.vertices, ctx.coarse_surface.vertices)
    assert np.array_equal(plain.coarse_surface.faces, ctx.coarse_surface.faces)
    pts = np.random.default_rng(0).uniform(-2.5, 2.5, (3000, 3))
    assert np.array_equal(plain.sdf.distance(pts), ctx.sdf.distance(pts))
    for a, b in zip(plain.sdf.project(pts), ctx.sdf.project(pts)):
        assert np.array_equal(a, b)
    fresh = original(SignedDistance, ctx.surface)
    assert np.array_equal(fresh.distance(pts), ctx.sdf.fine.distance(pts))


def test_chain_sets_the_later_steps_around_each_step():
    """Each step sees the steps after it, and nothing is left set after the run."""
    from vmesh.registry import _REGISTRY, register_filter

    seen = []
    try:

        @register_filter("h25_record_later", description="probe")
        def record(ctx):
            seen.append(tuple(s.filter for s in preload.LATER_STEPS.get()))

        FilterChain(["h25_record_later", "h25_record_later"]).run()
    finally:
        _REGISTRY.pop("h25_record_later", None)
    assert seen == [("h25_record_later",), ()]
    assert preload.LATER_STEPS.get() == ()


def test_prepare_surface_builds_what_the_later_steps_ask_of_the_surface():
    """A later check_coverage gets its surface facts (voxel step, volume; the smoothed copy
    stays lazy), a later two-step build_sdf its fine distance; other steps nothing."""
    from vmesh.chain import Step
    from vmesh.geometry import coverage

    surface = _sphere(3)
    token = preload.LATER_STEPS.set((Step("check_coverage"), Step("build_sdf", {"source": "fine"}), Step("write_mesh")))
    try:
        assert preload.prepare_surface(surface) == ["coverage facts"]
        facts = coverage.surface_facts(surface)
        assert {"voxel_step", "volume"} <= set(vars(facts)) and "smoothed" not in vars(facts)
        preload.LATER_STEPS.set((Step("build_sdf", {"source": "coarse", "refine_on_fine": True, "sign": "auto"}),))
        assert preload.prepare_surface(surface) == ["signed distance"]
        assert projection.cached_trees(surface)[("signed distance", "auto")] is projection.surface_distance(surface)
    finally:
        preload.LATER_STEPS.reset(token)
