"""Filter chains: building, TOML round trips, overrides, staged outputs."""

import json

import numpy as np
import pytest

import vmesh
from vmesh import FilterChain
from vmesh.errors import ChainError, InputError, ParameterError


def tube(n=24):
    import pyvista as pv

    cyl = pv.Cylinder(radius=1.0, height=4.0, resolution=n, capping=True).triangulate().clean()
    return vmesh.SurfaceMesh(np.asarray(cyl.points), cyl.faces.reshape(-1, 4)[:, 1:], name="tube")


def test_build_append_and_repr():
    chain = FilterChain(["surface_info"]).append("transform_surface", scale=2.0)
    assert [s.filter for s in chain] == ["surface_info", "transform_surface"]
    assert "transform_surface" in repr(chain)


def test_unknown_filter_in_chain():
    with pytest.raises(ParameterError, match="did you mean"):
        FilterChain(["surface_infoo"])


def test_bad_parameter_rejected_before_running(tmp_path):
    chain = FilterChain([("transform_surface", {"scale": -1.0})])
    with pytest.raises(ParameterError, match="below its minimum"):
        chain.run(surface=tube(), out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_toml_round_trip_runs_identically(tmp_path):
    chain = FilterChain(
        [("transform_surface", {"scale": 10.0, "translate": [1, 2, 3]}), "surface_info", ("write_surface_layer", {"filename": "t.ply"})],
        name="demo",
    )
    path = chain.save(tmp_path / "demo.toml")
    loaded = FilterChain.load(path)
    assert [(s.filter, s.params) for s in loaded.resolved()] == [(s.filter, s.params) for s in chain.resolved()]
    chain.run(surface=tube(), out_dir=tmp_path / "a")
    loaded.run(surface=tube(), out_dir=tmp_path / "b")
    a = vmesh.read_surface(tmp_path / "a" / "t.ply")
    b = vmesh.read_surface(tmp_path / "b" / "t.ply")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    # the resolved chain written next to the results loads and equals the original
    again = FilterChain.load(tmp_path / "a" / "chain.toml")
    assert [(s.filter, s.params) for s in again] == [(s.filter, s.params) for s in chain.resolved()]


def test_run_writes_report_and_resolved_chain(tmp_path):
    ctx = FilterChain(["surface_info"]).run(surface=tube(), out_dir=tmp_path / "o")
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["surface"]["closed"] is True
    assert "surface_info" in report["timings"]
    assert ctx.report.steps[0].peak_memory_mb > 0
    # CPU seconds per step (all threads): the measure that compares runs on a loaded machine
    assert report["steps"][0]["cpu_seconds"] >= 0 and ctx.report.steps[0].cpu_seconds >= 0


def test_append_keywords_and_a_filters_own_params_parameter():
    chain = FilterChain().append("decimate_surface", target_faces=500).append("decimate_surface", {"target_faces": 600})
    chain.append("decimate_surface", params={"target_faces": 700})
    chain.append("meshlab_filter", name="meshing_surface_subdivision_loop", params={"iterations": 2})
    assert [s.params for s in chain.steps] == [
        {"target_faces": 500},
        {"target_faces": 600},
        {"target_faces": 700},
        {"name": "meshing_surface_subdivision_loop", "params": {"iterations": 2}},
    ]


def test_unset_parameters_are_listed_and_auto_resets_them():
    chain = FilterChain([("decimate_surface", {"target_faces": 500})]).resolved()
    text = chain.to_toml()
    assert '# target_ratio = "auto"' in text and '# max_error = "auto"' in text and "target_faces = 500" in text
    again = FilterChain.from_dict(__import__("tomllib").loads(text)).resolved()
    assert again.steps[0].params == chain.steps[0].params
    reset = chain.with_overrides({"decimate_surface.target_faces": "auto"}).resolved()
    assert reset.steps[0].params["target_faces"] is None
    # a string parameter whose value is 'auto' keeps it
    assert FilterChain([("smooth_loop", {"region": "auto"})]).resolved().steps[0].params["region"] == "auto"


def test_overrides():
    chain = FilterChain([("transform_surface", {"scale": 2.0})]).with_overrides({"transform_surface.scale": 3.0})
    assert chain.steps[0].params["scale"] == 3.0
    with pytest.raises(ParameterError, match="not in this chain"):
        chain.with_overrides({"mesh_transfinite.order": 2})
    with pytest.raises(ParameterError, match="did you mean 'scale'"):
        chain.with_overrides({"transform_surface.scal": 2})


def test_missing_layer_detected_before_running():
    with pytest.raises(ChainError, match="needs the blocks layer"):
        FilterChain(["mesh_transfinite"]).run(surface=tube())


def test_a_layer_a_filter_only_updates_is_not_provided_by_it():
    """clean_skeleton relabels the surface and caps when they are there, but makes neither:
    a chain given only a skeleton must fail its check at a later step that reads the
    surface, not at run time."""
    with pytest.raises(ChainError, match="'build_sdf' needs the surface layer"):
        FilterChain(["clean_skeleton", "build_sdf"]).check_layers(["skeleton"])
    FilterChain(["clean_skeleton", "build_sdf"]).check_layers(["skeleton", "surface"])
    FilterChain(["build_sdf", "extract_skeleton", "clean_skeleton"]).check_layers(["surface"])  # extraction makes a skeleton


def test_failed_run_leaves_no_output(tmp_path):
    chain = FilterChain([("write_surface_layer", {"filename": "x.ply"}), ("surface_info", {"require_closed": True})])
    surf = tube()
    open_surf = surf.copy(faces=surf.faces[:-5])
    with pytest.raises(InputError, match="open boundary loops"):
        chain.run(surface=open_surf, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()
    # no staging folder left behind; what the run reached is in out.failed/
    assert [p.name for p in tmp_path.iterdir()] == ["out.failed"]
    assert (tmp_path / "out.failed" / "x.ply").is_file() and (tmp_path / "out.failed" / "failure.log").is_file()


def test_rerun_replaces_the_run_folder_and_refuses_other_outputs(tmp_path):
    out = tmp_path / "o"
    chain = FilterChain(["surface_info", ("write_surface_layer", {"filename": "a.ply"})])
    chain.run(surface=tube(), out_dir=out)
    (out / "mesh.msh").write_text("exported from the earlier mesh")
    FilterChain(["surface_info"]).run(surface=tube(), out_dir=out)
    assert sorted(p.name for p in out.iterdir()) == ["chain.toml", "report.json"]  # nothing stale
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]  # no staging or old folder left
    assert oct(out.stat().st_mode & 0o777) != oct(0o700)  # not mkdtemp's private mode
    # a file, or a folder holding something else, is refused before anything runs
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        chain.run(surface=tube(), out_dir=tmp_path / "f")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="not a vmesh run folder"):
        chain.run(surface=tube(), out_dir=tmp_path / "mine")
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_chain_file_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[step]\nfilter = 1")
    with pytest.raises(InputError, match="not valid TOML"):
        FilterChain.load(bad)
    bad.write_text("[chain]\nname='x'\n")
    with pytest.raises(InputError, match="no \\[\\[step\\]\\]"):
        FilterChain.load(bad)
    bad.write_text('[[step]]\nfilter = "nope_filter"\n')
    with pytest.raises(InputError, match="unknown filter"):
        FilterChain.load(bad)
    with pytest.raises(InputError, match="no such chain file or preset"):
        FilterChain.load("no_such_preset")
