"""Run any MeshLab filter, or a whole MeshLab filter script, as a step of a vmesh chain.

``meshlab_filter`` applies one pymeshlab filter by its python name with parameters
checked against pymeshlab's own parameter list; ``meshlab_script`` replays a ``.mlx``
script saved from the MeshLab GUI (Filters > Show current filter script > Save) or by
pymeshlab's ``MeshSet.save_filter_script``. Both work on the fine or the coarse surface.

Parameter values in a chain's TOML map to pymeshlab values as follows: numbers,
booleans and strings pass through (enumerations may be given by their label, e.g.
``loopweight = "Loop"``); a string ending in ``%`` (``"1.5%"``) is a
``PercentageValue`` (percent of the bounding-box diagonal); a table
``{percentage = 1.5}`` or ``{absolute = 0.2}`` is a ``PercentageValue`` or ``PureValue``.

Cap labels travel through the filter twice: as a per-face custom attribute, which
filters that keep the faces leave alone, and as face quality, which subdividing filters
copy to every child face (the custom attribute reaches only one child of each split
face). So caps survive filters that keep or subdivide faces; after filters that rebuild
the mesh (or overwrite face quality while changing the faces) the caps are dropped with a
warning.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .. import preprocess as pre
from ..context import _plain
from ..errors import ChainError, InputError, ParameterError
from ..registry import Parameter, register_filter, suggest
from ..surface import SurfaceMesh
from .preprocess_filters import cap_labels, set_caps

_LABEL_ATTRIBUTE = "vmesh_cap_id"

LAYER_PARAMETER = Parameter("layer", "str", "surface", "Surface layer to process: the fine input or the coarse copy.", choices=("surface", "coarse_surface"))


def pymeshlab_value(value, name: str = ""):
    """Convert a TOML/JSON value to what pymeshlab expects (see the module docstring)."""
    import pymeshlab

    if isinstance(value, str) and value.strip().endswith("%"):
        try:
            return pymeshlab.PercentageValue(float(value.strip()[:-1]))
        except ValueError:
            raise ParameterError(f"meshlab parameter '{name}': {value!r} is not a percentage") from None
    if isinstance(value, dict):
        if set(value) == {"percentage"}:
            return pymeshlab.PercentageValue(float(value["percentage"]))
        if set(value) == {"absolute"}:
            return pymeshlab.PureValue(float(value["absolute"]))
        raise ParameterError(f"meshlab parameter '{name}': a table must be {{percentage = x}} or {{absolute = x}}, got {value!r}")
    return value


def _meshset(ctx, layer):
    import pymeshlab

    surface = getattr(ctx, layer)
    if surface is None:
        raise InputError(f"there is no {layer} layer to process (add decimate_surface first)")
    if layer == "surface":
        labels = cap_labels(ctx).astype(np.float64)
        mesh = pymeshlab.Mesh(surface.vertices, surface.faces, f_scalar_array=labels)
        mesh.add_face_custom_scalar_attribute(labels, _LABEL_ATTRIBUTE)
    else:
        mesh = pymeshlab.Mesh(surface.vertices, surface.faces)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(mesh, surface.name or "surface")
    return ms, surface


def _take_result(ctx, ms, layer, surface: SurfaceMesh, what: str) -> None:
    """Store the MeshSet's current mesh back into ``layer``, carrying caps when possible."""
    m = ms.current_mesh()
    v = np.asarray(m.vertex_matrix(), np.float64)
    f = np.asarray(m.face_matrix(), np.int64)
    if len(f) == 0:
        raise ChainError(f"{what} left a mesh without faces (only triangle surfaces can continue in the chain)")
    same_faces = len(f) == surface.n_faces and len(v) == surface.n_vertices
    face_data = {k: a for k, a in surface.face_data.items() if same_faces and k != pre.CAP_LABEL}
    out = SurfaceMesh(v, f, name=surface.name, face_data=face_data)
    ctx.count(triangles=len(f), vertices=len(v), faces_change=len(f) - surface.n_faces)
    if layer != "surface":
        setattr(ctx, layer, out)
        return
    before = cap_labels(ctx)
    labels = None
    if same_faces:
        try:
            labels = np.rint(m.face_custom_scalar_attribute_array(_LABEL_ATTRIBUTE)).astype(np.int64)
        except Exception:  # the filter built a new mesh without the attribute
            labels = None
    if labels is None and m.has_face_scalar():
        quality = np.asarray(m.face_scalar_array(), np.float64)
        # labels only if the quality still holds them: whole numbers, all of them old labels
        if len(quality) == len(f) and np.all(quality == np.rint(quality)) and np.isin(quality, np.unique(before)).all():
            labels = quality.astype(np.int64)
    had_caps = bool(ctx.caps) or bool(before.any())
    if had_caps and labels is not None and len(labels) == len(f) and labels.min() >= 0:
        set_caps(ctx, out, labels, keep_names=True)
    else:
        ctx.surface = out
        if had_caps:
            ctx.caps = None
            ctx.warn(f"{what} rebuilt the mesh: caps were dropped (run detect_caps or cap_open_ends again)")


def _probe_meshset():
    """A MeshSet holding one tetrahedron: pymeshlab lists a filter's parameters only with a mesh loaded."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    tetra = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    ms.add_mesh(pymeshlab.Mesh(tetra, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])))
    return ms


def _checked_call(ms, name, params) -> dict:
    """``params`` converted for pymeshlab after checking the filter name and the parameter
    names (with suggestions) against pymeshlab's own lists on ``ms``."""
    import pymeshlab

    if name is None:
        raise ParameterError("meshlab_filter needs the name of a pymeshlab filter (parameter 'name')")
    available = pymeshlab.filter_list()
    if name not in available:
        raise ParameterError(f"unknown pymeshlab filter '{name}'" + suggest(name, available))
    try:
        valid = ms.filter_parameter_values(name)
    except pymeshlab.PyMeshLabException:  # filters that need more than one mesh: pymeshlab checks when it runs
        return {k: pymeshlab_value(v, k) for k, v in params.items()}
    for key in params:
        if key not in valid:
            raise ParameterError(
                f"pymeshlab filter '{name}' has no parameter '{key}'" + suggest(key, valid) + f" (parameters: {', '.join(valid) or 'none'})"
            )
    converted = {k: pymeshlab_value(v, k) for k, v in params.items()}
    try:
        ms.filter_parameter_values(name, **converted)
    except Exception as exc:  # pybind11 raises RuntimeError/TypeError on a wrong type
        raise ParameterError(f"pymeshlab filter '{name}': invalid parameter value ({_short(exc)}); defaults: {_defaults_text(valid)}") from None
    return converted


def _check_meshlab_filter(params):
    _checked_call(_probe_meshset(), params["name"], params["params"])


@register_filter(
    description="Apply any pymeshlab filter by name, its parameters checked against pymeshlab's own list.",
    parameters=[
        Parameter("name", "str", None, "(required) pymeshlab filter name, as in pymeshlab.filter_list() (e.g. meshing_isotropic_explicit_remeshing)."),
        Parameter("params", "dict", {}, "The filter's parameters; '2%' means a percentage of the bounding-box diagonal, {absolute = x} an absolute value."),
        LAYER_PARAMETER,
    ],
    optional_reads=("surface", "coarse_surface", "caps"),
    writes=("surface", "coarse_surface", "caps"),
    category="preprocessing",
    check=_check_meshlab_filter,
)
def meshlab_filter(ctx, name, params, layer):
    """Run ``MeshSet.apply_filter(name, **params)`` on a surface layer.

    The names and values of ``params`` are validated by pymeshlab before the filter
    runs; an unknown filter or parameter fails with the closest valid name. Values a
    filter returns (e.g. ``get_geometric_measures``) go into the report's ``meshlab``
    section.
    """
    import pymeshlab

    ms, surface = _meshset(ctx, layer)
    converted = _checked_call(ms, name, params)  # again on the real mesh: percentages, ranges
    try:
        result = ms.apply_filter(name, **converted)
    except pymeshlab.PyMeshLabException as exc:
        raise ChainError(f"pymeshlab filter '{name}' failed: {_short(exc)}") from None
    if result:
        ctx.report.sections.setdefault("meshlab", {})[name] = _plain(result, str)
    _take_result(ctx, ms, layer, surface, f"pymeshlab filter '{name}'")


def _script_filters(path: Path) -> list[str]:
    """The filter names of a ``.mlx`` script, after checking that it is one."""
    if not path.is_file():
        raise InputError("MeshLab filter script not found", path)
    if path.stat().st_size == 0:
        raise InputError("file is empty", path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(f"not a MeshLab filter script (XML error: {exc})", path) from None
    if root.tag != "FilterScript":
        raise InputError(f"not a MeshLab filter script (root element <{root.tag}>, expected <FilterScript>)", path)
    names = [el.get("name", "?") for el in root.iter("filter")] + [el.get("name", "?") for el in root.iter("xmlfilter")]
    if not names:
        raise InputError("MeshLab filter script has no filters", path)
    return names


def _check_meshlab_script(params):
    """The script is read before any step runs; its path is kept absolute, so that the
    chain.toml written with the run replays from any folder."""
    if params["path"] is None:
        raise ParameterError("meshlab_script needs the path of a .mlx script (parameter 'path')")
    path = Path(params["path"]).expanduser().resolve()
    _script_filters(path)
    return {**params, "path": str(path)}


@register_filter(
    description="Run a MeshLab filter script (.mlx, saved from the MeshLab GUI or pymeshlab) on a surface layer.",
    parameters=[
        Parameter("path", "path", None, "(required) The .mlx filter script; relative paths are taken from the current folder."),
        LAYER_PARAMETER,
    ],
    optional_reads=("surface", "coarse_surface", "caps"),
    writes=("surface", "coarse_surface", "caps"),
    category="preprocessing",
    check=_check_meshlab_script,
)
def meshlab_script(ctx, path, layer):
    """Replay every filter of a MeshLab ``.mlx`` script, in order, on the surface.

    The script's filters are listed in the report's ``meshlab_script`` section.
    """
    import pymeshlab

    path = Path(path)
    names = _script_filters(path)
    ms, surface = _meshset(ctx, layer)
    try:
        ms.load_filter_script(str(path))
        ms.apply_filter_script()
    except pymeshlab.PyMeshLabException as exc:
        raise InputError(f"MeshLab script failed ({_short(exc)}); its filters: {', '.join(names)}", path) from None
    ctx.report.sections["meshlab_script"] = {"path": str(path), "filters": names}
    ctx.count(script_filters=len(names))
    _take_result(ctx, ms, layer, surface, f"MeshLab script {path.name}")


def _defaults_text(values: dict) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in values.items())


def _short(exc) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text.split("Please report")[0].strip()[:200]

