"""The filter contract, checked: every registered filter runs against a recording context
that fails on any read or write of a layer the filter does not declare (issue 20).

A filter's ``reads`` and ``optional_reads`` say which layers it may look at, its
``writes`` which it may set or change in place. The chains below run every registered
filter on small inputs; :class:`RecordingContext` notes each layer access of the step
that is running, and compares pickled snapshots of the layers before and after each step
to catch changes made in place (a label array added to the mesh, caps cleared). The
prefix cache (:mod:`vmesh.cache`) stores exactly the declared writes, so a missing
declaration shows up there as a wrong restored layer: see the last test.
"""

import pickle

import numpy as np
import pytest

from conftest import synthetic_case
from vmesh.chain import FilterChain
from vmesh.context import Context
from vmesh.registry import LAYERS, filter_list, get_filter

#: layers compared before and after each step (the signed distance is only queried and
#: too large to pickle for every step)
SNAPSHOT_LAYERS = tuple(layer for layer in LAYERS if layer != "sdf")


class RecordingContext(Context):
    """A :class:`~vmesh.context.Context` that records, per running step, which layers
    are read and written, and collects every access the step's filter does not declare."""

    def __init__(self, *args, **kwargs):
        object.__setattr__(self, "violations", [])
        object.__setattr__(self, "seen", set())
        object.__setattr__(self, "_written", set())
        object.__setattr__(self, "_before", {})
        super().__init__(*args, **kwargs)

    def __getattribute__(self, name):
        if name in LAYERS:
            step = object.__getattribute__(self, "_step") if "_step" in object.__getattribute__(self, "__dict__") else None
            if step is not None:
                f = get_filter(step.filter)
                if name not in (*f.reads, *f.optional_reads) and name not in object.__getattribute__(self, "_written"):
                    self.violations.append(f"{step.filter} reads '{name}' undeclared")
        return object.__getattribute__(self, name)

    def __setattr__(self, name, value):
        d = self.__dict__
        if name == "_step":
            if value is not None:
                self._begin(value.filter)
            elif d.get("_step") is not None:
                self._end(d["_step"].filter)
        elif name in LAYERS and d.get("_step") is not None:
            f = get_filter(d["_step"].filter)
            if name not in f.writes:
                self.violations.append(f"{d['_step'].filter} writes '{name}' undeclared")
            self._written.add(name)
        object.__setattr__(self, name, value)

    def _snapshot(self):
        out = {}
        for layer in SNAPSHOT_LAYERS:
            value = self.__dict__.get(layer)
            try:
                out[layer] = pickle.dumps(value, protocol=5)
            except Exception:  # an object that cannot be pickled is not compared
                out[layer] = None
        return out

    def _begin(self, name):
        self.seen.add(name)
        self._written.clear()
        object.__setattr__(self, "_before", self._snapshot())

    def _end(self, name):
        f = get_filter(name)
        after = self._snapshot()
        for layer, before in self._before.items():
            if before is not None and after[layer] is not None and before != after[layer] and layer not in f.writes and layer not in self._written:
                self.violations.append(f"{name} changes '{layer}' in place undeclared")
        self._written.clear()


def _mlx(tmp_path):
    """A one-filter MeshLab script (remove duplicate vertices)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.eye(3), np.array([[0, 1, 2]])))
    ms.meshing_remove_duplicate_vertices()
    path = tmp_path / "dedup.mlx"
    ms.save_filter_script(str(path))
    return path


def _chains(tmp_path):
    """(name, chain, with the committed skeleton?) covering every registered filter."""
    _, skeleton = synthetic_case("straight_tube")
    preprocess = [
        "surface_info",
        ("transform_surface", {"scale": 1.0, "translate": [0.5, 0.0, 0.0]}),
        ("scale_radius", {"scale": 1.05}),
        "repair_surface",
        ("meshlab_filter", {"name": "meshing_remove_duplicate_vertices"}),
        ("meshlab_script", {"path": str(_mlx(tmp_path))}),
        "cap_open_ends",
        "detect_caps",
        ("smooth_loop", {"iterations": 1}),
        "decimate_surface",
        ("build_sdf", {"source": "coarse", "refine_on_fine": True}),
        ("measure_sdf", {"points": [1000], "octree": False}),
    ]
    mesh = [
        "estimate_radii",
        "clean_skeleton",
        "resample_skeleton",
        ("tag_skeleton", {"branches": True}),
        "build_block_structure",
        "mesh_transfinite",
        "label_elements",
        ("compute_quality", {"histogram": ""}),
        "check_coverage",
        "write_mesh",
        "write_blocks",
        "write_skeleton_layer",
        "write_surface_layer",
        ("export_mesh", {"filename": "mesh.msh"}),
        "export_meshlab",
        ("render_skeleton", {"width": 160, "height": 120}),
    ]
    extract = [
        "repair_surface",
        "cap_open_ends",
        ("decimate_surface", {"output": "surface", "target_ratio": 0.5}),
        "detect_caps",
        "build_sdf",
        ("extract_skeleton", {"only_if_missing": False}),
        ("load_skeleton", {"path": str(skeleton)}),
    ]
    return [("read skeleton", FilterChain(preprocess + mesh), True), ("extracted skeleton", FilterChain(extract), False)]


@pytest.mark.slow
def test_every_filter_keeps_its_declared_contract(tmp_path):
    surface, skeleton = synthetic_case("straight_tube")
    seen, violations = set(), []
    for k, (name, chain, with_skeleton) in enumerate(_chains(tmp_path)):
        ctx = RecordingContext()
        chain.run(surface=surface, skeleton=skeleton if with_skeleton else None, out_dir=tmp_path / f"run{k}", context=ctx)
        seen |= ctx.seen
        violations += [f"{name}: {v}" for v in dict.fromkeys(ctx.violations)]
    assert violations == [], "undeclared layer access:\n" + "\n".join(violations)
    unexercised = sorted(set(filter_list()) - seen)
    assert unexercised == [], f"filters no contract chain runs (add them to _chains): {unexercised}"


def test_recording_context_catches_undeclared_access():
    """The recorder itself: an undeclared read, an undeclared set and an in-place change
    of a layer are each reported, declared access is not."""
    from vmesh.registry import _REGISTRY, register_filter

    names = ("_contract_probe_read", "_contract_probe_set", "_contract_probe_inplace", "_contract_probe_ok")
    try:
        @register_filter(names[0], description="probe", reads=("surface",))
        def probe_read(ctx):
            return ctx.skeleton

        @register_filter(names[1], description="probe", reads=("surface",))
        def probe_set(ctx):
            ctx.caps = []

        @register_filter(names[2], description="probe", reads=("surface",))
        def probe_inplace(ctx):
            ctx.surface.vertices[0, 0] += 1.0

        @register_filter(names[3], description="probe", reads=("surface",), optional_reads=("skeleton",), writes=("surface", "caps"))
        def probe_ok(ctx):
            ctx.caps = [] if ctx.skeleton is None else None
            ctx.surface.vertices[0, 0] += 1.0

        ctx = RecordingContext()
        surface, _ = synthetic_case("straight_tube")
        FilterChain(list(names)).run(surface=surface, context=ctx)
        assert sorted(set(ctx.violations)) == [
            "_contract_probe_inplace changes 'surface' in place undeclared",
            "_contract_probe_read reads 'skeleton' undeclared",
            "_contract_probe_set writes 'caps' undeclared",
        ]
    finally:
        for n in names:
            _REGISTRY.pop(n, None)


def test_register_filter_checks_parameter_names_against_signature():
    from vmesh.registry import Parameter, _REGISTRY, register_filter

    with pytest.raises(ValueError, match="declared but not taken: b.*taken but not declared: c"):
        register_filter("_contract_bad", description="x", parameters=[Parameter("a", "int", 1, "a"), Parameter("b", "int", 1, "b")])(lambda ctx, a, c: None)
    with pytest.raises(ValueError, match="first argument must be the context"):
        register_filter("_contract_bad2", description="x")(lambda *, a=1: None)
    assert "_contract_bad" not in _REGISTRY and "_contract_bad2" not in _REGISTRY


def test_cached_prefix_restores_a_transformed_skeleton():
    """transform_surface moves the skeleton with the surface; a cached prefix holding it
    must restore both (it restored the transformed surface with the input's skeleton)."""
    from vmesh.cache import PrefixCache
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    surface, skeleton = synthetic_case("straight_tube")
    chain = FilterChain([("transform_surface", {"scale": 2.0, "translate": [1.0, 0.0, 0.0]}), "repair_surface", "cap_open_ends", "build_sdf"])
    cache = PrefixCache(max_entries=2)
    runs = [chain.run(surface=read_surface(surface), skeleton=read_skeleton(skeleton), cache=cache) for _ in range(2)]
    assert [s.cached for s in runs[1].report.steps] == [True] * 4
    raw = read_skeleton(skeleton)
    for ctx in runs:
        np.testing.assert_allclose(ctx.skeleton.points, raw.points * 2.0 + [1.0, 0.0, 0.0])
        np.testing.assert_allclose(ctx.skeleton.radii, raw.radii * 2.0)


def test_a_prefix_without_the_window_split_is_not_keyed_on_the_centerline():
    """cap_open_ends reads the centerline only with ``split_windows``: without it, runs of one
    surface with different centerlines (an uncertainty study) share the cached prefix."""
    from vmesh.cache import PrefixCache
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    surface, skeleton = synthetic_case("straight_tube")
    cache = PrefixCache(max_entries=2)

    def key(scale, split):
        sk = read_skeleton(skeleton)
        sk.radii = sk.radii * scale
        ctx = Context(surface=read_surface(surface), skeleton=sk)
        chain = FilterChain(["repair_surface", ("cap_open_ends", {"split_windows": split}), "build_sdf"])
        return cache.key(ctx, chain.steps)

    assert key(1.0, False) == key(1.1, False)
    assert key(1.0, True) != key(1.1, True)
