"""Filter registry: discovery, parameter validation, suggestions."""

import pytest

import vmesh
from vmesh.errors import ParameterError
from vmesh.registry import Parameter


def test_filter_list_has_every_stage():
    names = vmesh.filter_list()
    assert len(names) == len(set(names))
    for name in ("surface_info", "mesh_transfinite", "label_elements", "compute_quality", "check_coverage", "write_mesh"):
        assert name in names


@pytest.mark.parametrize("preset", ["default", "batch_sweep"])
def test_meshing_chains_check_coverage_after_quality(preset):
    """Every run of the meshing presets checks that the mesh covers the vessel (issue 17)."""
    steps = [s.filter for s in vmesh.FilterChain.load(preset).steps]
    assert steps[steps.index("compute_quality") + 1] == "check_coverage"


def test_every_filter_signature_matches_its_parameters():
    """register_filter refuses a mismatch; this lists every registered filter's agreement."""
    import inspect

    for name in vmesh.filter_list():
        f = vmesh.get_filter(name)
        taken = list(inspect.signature(f.function).parameters)[1:]
        assert sorted(taken) == sorted(f.parameter_names), name


def test_every_filter_is_documented():
    for name in vmesh.filter_list():
        f = vmesh.get_filter(name)
        assert f.description and f.description[0].isupper(), name
        for p in f.parameters:
            assert p.description, f"{name}.{p.name} has no description"
            if p.default is not None:
                assert p.validate(p.default, name) == p.default or p.type == "float_list"


def test_print_parameter_list(capsys):
    vmesh.print_filter_parameter_list("mesh_transfinite")
    out = capsys.readouterr().out
    assert "first_layer : float = 0.02" in out and "× radius" in out and "[1, 4]" in out


def test_unknown_filter_suggests_closest():
    with pytest.raises(ParameterError, match="did you mean 'mesh_transfinite'"):
        vmesh.get_filter("mesh_transfinit")


def test_unknown_parameter_suggests_closest():
    f = vmesh.get_filter("mesh_transfinite")
    with pytest.raises(ParameterError, match="did you mean 'first_layer'"):
        f.resolve({"first_layr": 0.1})


@pytest.mark.parametrize(
    "value, message",
    [("2", "must be of type int"), (True, "must be of type int"), (0, "below its minimum"), (99, "above its maximum")],
)
def test_bad_values_rejected(value, message):
    with pytest.raises(ParameterError, match=message):
        vmesh.get_filter("mesh_transfinite").resolve({"order": value})


def test_choices_rejected_with_suggestion():
    with pytest.raises(ParameterError, match="did you mean 'uniform'"):
        vmesh.get_filter("mesh_transfinite").resolve({"grading": "unifrom"})


def test_int_accepted_for_float_and_defaults_filled():
    p = vmesh.get_filter("mesh_transfinite").resolve({"first_layer": 1})
    assert p["first_layer"] == 1.0 and isinstance(p["first_layer"], float)
    assert p["order"] == 1


def test_parameter_type_checked_at_definition():
    with pytest.raises(ValueError):
        Parameter("x", "complex", 1, "bad type")
