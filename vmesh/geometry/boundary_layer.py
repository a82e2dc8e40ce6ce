"""Boundary-layer controls for CFD: lengths with units, the four boundary-layer quantities
(first-layer height, total thickness, number of layer elements, growth ratio), a first-layer
height from a target y+, and measuring the first-cell height of a finished mesh.

The boundary layer of a vmesh mesh is the ring of boundary-layer blocks next to the wall;
its elements are graded inside those blocks (never extra elements). Of

- ``h1`` the first element's wall-normal height,
- ``T`` the total thickness of the boundary-layer blocks,
- ``n`` the number of elements across them,
- ``q`` the ratio of consecutive element heights,

related by ``T = h1 (q**n - 1) / (q - 1)``, any three fix the fourth
(:func:`resolve_boundary_layer`). Without ``T`` the thickness is the block structure's
(``build_block_structure.layer_thickness`` × wall distance, varying along the vessel).
With ``T`` the inner corners of the boundary-layer blocks are moved along their radial block
edges so that every such edge is ``T`` long (:func:`set_layer_thickness`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from ..blocks import AXIS_LAYER, HEX_EDGE_AXIS, HEX_EDGES, LAYER_BOUNDARY, LAYER_RING
from ..errors import MeshingError, ParameterError
from .layer_placement import layer_lines, offset_layer, place_first_layer, wall_normals

#: Metres per length unit.
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}
#: Units an input surface may be given in (``vmesh run --units``).
INPUT_UNITS = ("mm", "cm", "m")
#: Inputs whose bounding-box diagonal is below this are guessed to be in metres, else mm.
METRE_GUESS_BELOW = 2.0
#: A guessed mm is doubted (a warning, :func:`resolve_units`) below this diagonal (a vessel
#: model under 1 cm across) or below :data:`MM_SMALL_RADIUS` median vessel radius (finer
#: than imaged human vessels: BraVa's whole-brain tree has a median 0.42 mm); a model in
#: cm read as mm looks like this (kd_lima: diagonal 10.7, median radius 0.106).
MM_SMALL_DIAGONAL = 10.0
MM_SMALL_RADIUS = 0.2

_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ]*)\s*$")


def guess_units(diagonal: float) -> str:
    """Units of a vessel surface from its bounding-box diagonal: ``m`` below
    :data:`METRE_GUESS_BELOW` (no vessel is 2 mm across its whole extent), else ``mm``
    (segmentations are in mm; cm is never guessed: give it)."""
    return "m" if diagonal < METRE_GUESS_BELOW else "mm"


def resolve_units(ctx) -> dict:
    """The input's length unit: ``ctx.inputs["units"]`` (``vmesh run --units``) or guessed
    from the surface size. Recorded once in ``report.json`` (``units``) and the summary."""
    known = ctx.report.sections.get("units")
    if known:
        return known
    given = ctx.inputs.get("units")
    if given:
        if given not in INPUT_UNITS:
            raise ParameterError(f"--units {given!r} is not one of {', '.join(INPUT_UNITS)}")
        units = {"length": given, "source": "given (--units)"}
    else:
        diagonal = float(ctx.surface.diagonal) if ctx.surface is not None else float("nan")
        length = guess_units(diagonal) if math.isfinite(diagonal) else "mm"
        units = {"length": length, "source": f"guessed from the bounding-box diagonal {diagonal:.4g} (give --units mm|cm|m)"}
        if doubt := _guess_doubt(length, diagonal, ctx.skeleton):
            ctx.warn(doubt)
    units["metres_per_unit"] = LENGTH_UNITS[units["length"]]
    ctx.report.sections["units"] = units
    ctx.count(units=units["length"])
    return units


def parse_length(text: str, units: str, name: str) -> float:
    """A length such as ``"0.05mm"``, ``"50um"`` or ``"0.05"`` (no unit: the mesh's units),
    in the mesh's ``units``.

    Raises
    ------
    ParameterError
        Not a positive number with an optional known unit.
    """
    m = _LENGTH.match(str(text))
    if not m or (m.group(2) and m.group(2) not in LENGTH_UNITS):
        raise ParameterError(f"{name} = {text!r}: expected a length such as 0.05mm (units: {', '.join(LENGTH_UNITS)}; none = the mesh's units)")
    value = float(m.group(1))
    if not value > 0:
        raise ParameterError(f"{name} = {text!r} must be positive")
    unit = m.group(2) or units
    return value * LENGTH_UNITS[unit] / LENGTH_UNITS[units]


def first_layer_from_y_plus(y_plus: float, velocity: float, density: float, viscosity: float, length: float) -> float:
    """First-layer height (m) for a target ``y_plus`` from the flat-plate skin friction.

    ``Re = rho U L / mu``, ``Cf = 0.026 Re**(-1/7)`` (turbulent flat plate, White's fit),
    wall shear ``tau = Cf rho U**2 / 2``, friction velocity ``u_tau = sqrt(tau / rho)``,
    height ``y = y+ mu / (rho u_tau)``. An estimate for choosing a mesh, as in every
    y+ calculator; in laminar vessel flow it errs on the thin (safe) side.

    Parameters
    ----------
    y_plus : float
        Target y+ of the first element's wall-normal height.
    velocity : float
        Free-stream (bulk) velocity, m/s.
    density : float
        kg/m³ (blood: about 1060).
    viscosity : float
        Dynamic viscosity, Pa·s (blood: about 3.5e-3).
    length : float
        Reference length, m (the vessel diameter).
    """
    for name, v in (("y_plus", y_plus), ("velocity", velocity), ("density", density), ("viscosity", viscosity), ("length", length)):
        if not v > 0:
            raise ParameterError(f"y+ estimate: {name} must be positive, got {v}")
    reynolds = density * velocity * length / viscosity
    cf = 0.026 * reynolds ** (-1.0 / 7.0)
    u_tau = math.sqrt(0.5 * cf * velocity**2)
    return y_plus * viscosity / (density * u_tau)


def series(q: float, n: int) -> float:
    """``1 + q + ... + q**(n-1)``: the total thickness of n elements in units of the first."""
    return float(n) if abs(q - 1.0) < 1e-12 else (q**n - 1.0) / (q - 1.0)


def ratio_for(h1: float, thickness: float, n: int) -> float:
    """Growth ratio q with ``h1 series(q, n) = thickness`` (bisection on log q; q < 1 when
    the first element is thicker than the uniform ``thickness / n``)."""
    target = thickness / h1
    lo, hi = -20.0 / max(n, 1), 20.0 / max(n - 1, 1)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if series(math.exp(mid), n) < target:
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))


@dataclass(frozen=True)
class BoundaryLayer:
    """The resolved boundary layer (lengths in the mesh's units).

    ``first_height`` absolute, or ``first_relative`` × local radius, or neither (growth or
    uniform grading); ``thickness`` absolute or ``None`` (the block structure's);
    ``elements`` across the layer; ``growth`` when the ratio is given rather than the height.
    """

    elements: int
    first_height: float | None = None
    first_relative: float | None = None
    thickness: float | None = None
    growth: float | None = None

    def describe(self, units: str) -> dict:
        out = {"elements": self.elements}
        if self.first_height is not None:
            out["first_height"] = f"{self.first_height:.6g} {units}"
        if self.first_relative is not None:
            out["first_layer"] = f"{self.first_relative:.6g} x radius"
        if self.thickness is not None:
            out["thickness"] = f"{self.thickness:.6g} {units}"
        if self.growth is not None:
            out["growth"] = self.growth
        return out


def resolve_boundary_layer(first_height, first_relative, thickness, elements, growth, block_thickness=None) -> BoundaryLayer:
    """Any consistent three of (first height, thickness, elements, growth) -> the layer.

    Parameters
    ----------
    first_height : float or None
        Absolute first-element height (mesh units).
    first_relative : float or None
        First-element height relative to the local radius (used when ``first_height`` is None).
    thickness : float or None
        Absolute total thickness; ``None``: the block structure's.
    elements : int
        Elements across the layer; 0 = derive it.
    growth : float or None
        Growth ratio; ``None`` = not given.
    block_thickness : float, optional
        Median thickness of the block structure's layer, to derive ``elements`` without ``thickness``.

    Raises
    ------
    ParameterError
        One line: an under-determined or inconsistent set.
    """
    h1 = first_height
    given = [k for k, v in (("first height", h1 if h1 is not None else first_relative), ("thickness", thickness),
                            ("elements", elements or None), ("growth", growth)) if v is not None]
    if elements == 0:
        if h1 is None or growth is None:
            raise ParameterError(
                f"boundary layer: elements_layer = 0 (derive the element count) needs an absolute first-layer height and a growth ratio (grading = growth); given: {', '.join(given) or 'nothing'}"
            )
        total = thickness if thickness is not None else block_thickness
        if total is None or not total > h1:
            raise ParameterError(f"boundary layer: the first-layer height {h1:.4g} is not below the layer thickness {total}")
        n = max(1, round(math.log(1.0 + total * (growth - 1.0) / h1) / math.log(growth)) if growth > 1.0 else round(total / h1))
        return BoundaryLayer(n, first_height=h1, thickness=thickness)
    if h1 is not None and growth is not None:
        implied = h1 * series(growth, elements)
        if thickness is not None and abs(implied - thickness) > 0.01 * thickness:
            raise ParameterError(
                f"boundary layer: inconsistent first-layer height {h1:.4g}, thickness {thickness:.4g}, {elements} elements and growth {growth:g} "
                f"(they give a thickness of {implied:.4g}; leave one of the four out)"
            )
        return BoundaryLayer(elements, first_height=h1, thickness=implied)
    if thickness is not None and h1 is not None and h1 * elements > thickness * (1 + 1e-9) and elements > 1:
        raise ParameterError(f"boundary layer: {elements} elements of first height {h1:.4g} do not fit in the thickness {thickness:.4g} with growth >= 1")
    if h1 is not None:
        return BoundaryLayer(elements, first_height=h1, thickness=thickness)
    if growth is not None:
        return BoundaryLayer(elements, thickness=thickness, growth=growth)
    return BoundaryLayer(elements, first_relative=first_relative, thickness=thickness)


def layer_edges(blocks) -> tuple[np.ndarray, np.ndarray]:
    """(wall vertex, inner vertex) of every radial edge of the boundary-layer blocks (unique)."""
    bl = np.flatnonzero(blocks.block_layer == LAYER_BOUNDARY)
    if len(bl) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    kinds = blocks.axis_kind[bl][:, HEX_EDGE_AXIS]  # (b, 12)
    ends = blocks.hexes[bl][:, HEX_EDGES]  # (b, 12, 2)
    sel = kinds == AXIS_LAYER
    a, b = ends[sel][:, 0], ends[sel][:, 1]
    on_a, on_b = blocks.vertex_on_surface[a], blocks.vertex_on_surface[b]
    radial = on_a ^ on_b
    wall = np.where(on_a, a, b)[radial]
    inner = np.where(on_a, b, a)[radial]
    pairs = np.unique(np.c_[wall, inner], axis=0)
    return pairs[:, 0], pairs[:, 1]


def block_layer_thickness(blocks) -> np.ndarray:
    """Lengths of the radial edges of the boundary-layer blocks."""
    wall, inner = layer_edges(blocks)
    return np.linalg.norm(blocks.vertices[inner] - blocks.vertices[wall], axis=1)


def set_layer_thickness(blocks, thickness: float):
    """A copy of ``blocks`` whose boundary-layer blocks are ``thickness`` thick: every inner
    corner moves along its radial edge (the mean of its edges' targets where it has several).

    Raises
    ------
    MeshingError
        When a block would turn inside out (the layer is thicker than the room to the core).
    """
    wall, inner = layer_edges(blocks)
    if len(wall) == 0:
        raise MeshingError("boundary-layer thickness given but the block structure has no boundary-layer blocks")
    V = blocks.vertices
    d = V[inner] - V[wall]
    target = V[wall] + thickness * d / np.linalg.norm(d, axis=1)[:, None]
    total = np.zeros_like(V)
    count = np.zeros(len(V))
    np.add.at(total, inner, target)
    np.add.at(count, inner, 1.0)
    moved = V.copy()
    has = count > 0
    moved[has] = total[has] / count[has, None]
    out = replace(blocks, vertices=moved)
    jac = out.corner_jacobians().min(axis=1)
    if (jac <= 0).any():
        bad = np.flatnonzero(jac <= 0)
        raise MeshingError(
            f"a boundary layer {thickness:.4g} thick turns {len(bad)} blocks inside out (blocks {bad[:10].tolist()}; "
            f"the layer blocks are {np.median(np.linalg.norm(d, axis=1)):.4g} thick on average): give a thinner boundary_layer_thickness"
        )
    return out


def first_cell_heights(mesh, local=None) -> np.ndarray:
    """Wall-normal height of the element on each wall face (the first-cell height a CFD
    solver sees): the vector from the wall face's centre to the opposite face's centre,
    projected on the wall face's normal. ``local``: the boundary faces' local faces
    (:func:`~vmesh.io.export.boundary_local_faces`, computed when None)."""
    from ..io.export import boundary_local_faces, face_corner_ids, tensor_faces

    wall = np.flatnonzero(np.asarray(mesh.boundary_ids) == 0)
    if len(wall) == 0:
        return np.zeros(0)
    p = mesh.order
    corners = tensor_faces(p)[:, face_corner_ids(p)]  # (6, 4)
    local = (boundary_local_faces(mesh) if local is None else local)[wall]
    cells = np.asarray(mesh.cells)[np.asarray(mesh.boundary_cells)[wall]]
    own = mesh.points[np.take_along_axis(cells, corners[local], axis=1)]  # (k, 4, 3)
    opp = mesh.points[np.take_along_axis(cells, corners[local ^ 1], axis=1)]
    normal = np.cross(own[:, 2] - own[:, 0], own[:, 3] - own[:, 1])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    return np.abs(np.einsum("ij,ij->i", opp.mean(axis=1) - own.mean(axis=1), normal))


def _guess_doubt(length: str, diagonal: float, skeleton) -> str | None:
    """A warning when a guessed unit is not mm (why it was guessed) or when mm is guessed
    for a model small for mm vessels (:data:`MM_SMALL_DIAGONAL`, :data:`MM_SMALL_RADIUS`)."""
    if length == "m":
        return (f"length unit m assumed: the surface's bounding-box diagonal {diagonal:.4g} is below {METRE_GUESS_BELOW:g}, "
                "too small for a vessel model in mm; give --units mm|cm if it is not in metres")
    radii = np.asarray(skeleton.radii, float) if skeleton is not None else np.zeros(0)
    radius = float(np.median(radii[np.isfinite(radii) & (radii > 0)])) if np.any(np.isfinite(radii) & (radii > 0)) else math.nan
    if diagonal < MM_SMALL_DIAGONAL or radius < MM_SMALL_RADIUS:
        return (f"length unit mm assumed (bounding-box diagonal {diagonal:.4g}, median vessel radius {radius:.3g}): small for "
                f"a vessel in mm (under {MM_SMALL_DIAGONAL:g} across or a radius under {MM_SMALL_RADIUS:g}), as a model in cm "
                "read as mm is; give --units cm, or --units mm to confirm")
    return None


def setup_boundary_layer(ctx, refinement, elements_layer, grading, first_layer, growth, first_layer_height, boundary_layer_thickness,
                         y_plus, flow_velocity, flow_density, flow_viscosity, reference_length) -> dict:
    """Resolve ``mesh_transfinite``'s boundary-layer parameters (see the filter) into
    :class:`~vmesh.geometry.transfinite.Refinement` fields; with a total thickness, replace
    ``ctx.blocks`` by blocks whose boundary-layer ring has it. Records ``boundary_layer`` in
    the report.

    Returns
    -------
    dict
        ``layer``, ``first_layer``, ``first_layer_absolute`` and ``growth`` for the Refinement.
    """
    units = resolve_units(ctx)
    u, metres = units["length"], units["metres_per_unit"]
    blocks = ctx.blocks
    h1 = parse_length(first_layer_height, u, "first_layer_height") if first_layer_height else None
    section = {"units": u}
    if y_plus > 0:
        if h1 is not None:
            raise ParameterError("give first_layer_height or y_plus, not both")
        if reference_length:
            length = parse_length(reference_length, u, "reference_length")
        else:
            length = 2.0 * float(np.max(blocks.block_radius))  # the widest vessel diameter
        h1 = first_layer_from_y_plus(y_plus, flow_velocity, flow_density, flow_viscosity, length * metres) / metres
        section["y_plus"] = {"y_plus": y_plus, "velocity_m_s": flow_velocity, "density_kg_m3": flow_density, "viscosity_Pa_s": flow_viscosity,
                             "reference_length": f"{length:.6g} {u}", "first_height": f"{h1:.6g} {u}", "estimate": "flat plate, Cf = 0.026 Re^(-1/7)"}
    thickness = parse_length(boundary_layer_thickness, u, "boundary_layer_thickness") if boundary_layer_thickness else None
    q = growth if grading == "growth" else (1.0 if grading == "uniform" else None)
    relative = first_layer if grading == "first_layer" and h1 is None else None
    block_t = block_layer_thickness(blocks)
    bl = resolve_boundary_layer(h1, relative, thickness, elements_layer, q, float(np.median(block_t)) if len(block_t) else None)
    if bl.thickness is not None:
        ctx.blocks = set_layer_thickness(blocks, bl.thickness)
    elif bl.first_height is not None and len(block_t) and bl.first_height * bl.elements > np.min(block_t):
        ctx.warn(
            f"first-layer height {bl.first_height:.4g} {u} x {bl.elements} elements exceeds the boundary-layer blocks' thickness "
            f"(min {np.min(block_t):.4g} {u}): the layer is uniform there (give fewer elements_layer or a boundary_layer_thickness)"
        )
    section.update(bl.describe(u))
    ctx.report.sections["boundary_layer"] = section
    out = {"layer": bl.elements * refinement, "first_layer": None, "first_layer_absolute": False, "growth": None}
    section["target_first_height"] = bl.first_height
    section["target_thickness"] = bl.thickness
    if bl.first_height is not None:
        out.update(first_layer=bl.first_height, first_layer_absolute=True)
    elif bl.first_relative is not None:
        out["first_layer"] = bl.first_relative / refinement
    elif bl.growth is not None and bl.growth != 1.0:
        out["growth"] = bl.growth ** (1.0 / refinement)
    return out


def first_edge_lengths(mesh, local=None) -> np.ndarray:
    """Length of the element edge from each corner of each wall face to the next node off
    the wall (4 per wall face): the first-layer height along the boundary-layer lines.
    ``local`` as :func:`first_cell_heights`'."""
    from ..io.export import boundary_local_faces, face_corner_ids, tensor_faces

    wall = np.flatnonzero(np.asarray(mesh.boundary_ids) == 0)
    if len(wall) == 0:
        return np.zeros(0)
    p = mesh.order
    local = (boundary_local_faces(mesh) if local is None else local)[wall]
    corners = tensor_faces(p)[:, face_corner_ids(p)][local]  # (k, 4) tensor ids, i + (p+1)(j + (p+1)k)
    axis = local // 2
    step = (p + 1) ** axis * np.where(local % 2 == 0, 1, -1)  # one element inwards along the face's axis
    cells = np.asarray(mesh.cells)[np.asarray(mesh.boundary_cells)[wall]]
    inner = np.take_along_axis(cells, corners + p * step[:, None], axis=1)
    return np.linalg.norm(mesh.points[inner] - mesh.points[np.take_along_axis(cells, corners, axis=1)], axis=2).ravel()


def _stats(values: np.ndarray, target: float | None) -> dict:
    out = {k: float(f(values)) for k, f in (("median", np.median), ("mean", np.mean), ("min", np.min), ("max", np.max))}
    if target:
        out["within_5_percent"] = float(np.mean(np.abs(values / target - 1.0) <= 0.05))
    return out


def record_first_layer(ctx, mesh, target: float | None = None) -> None:
    """Measure the first-layer heights at the wall into the report's ``boundary_layer``:
    wall-normal per wall node (:func:`first_node_heights`), wall-normal per wall face
    (:func:`first_cell_heights`) and along the layer lines per wall-face corner
    (:func:`first_edge_lengths`), with the fraction within 5 % of ``target``."""
    from ..io.export import boundary_local_faces

    if not (np.asarray(mesh.boundary_ids) == 0).any():
        return
    local = boundary_local_faces(mesh)  # once for both measures
    h = first_cell_heights(mesh, local)
    section = ctx.report.sections.setdefault("boundary_layer", {})
    section["measured_first_height"] = _stats(h, target)
    section["measured_first_edge"] = _stats(first_edge_lengths(mesh, local), target)
    nodes, lines = first_node_heights(mesh, whole_lines=False)  # the heights need the first elements only
    if len(nodes) == 0:
        ctx.count(first_height=float(np.median(h)))
        return
    stats = section["measured_first_node_height"] = _stats(nodes, target)
    ctx.count(first_height=float(np.median(nodes)))
    if target:
        miss = np.abs(nodes / target - 1.0) > 0.05
        caps = np.isin(lines[:, 0], np.asarray(mesh.boundary_faces)[np.asarray(mesh.boundary_ids) > 0])
        stats["outside_5_percent"] = {"lines": int(miss.sum()), "on_cap_rims": int((miss & caps).sum())}
        ctx.count(first_height_within_5=round(float(stats["within_5_percent"]), 4))


def first_node_heights(mesh, whole_lines: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The first-layer height at each wall node: the distance, along the wall normal
    (:func:`wall_normals`), from the wall node to the first element corner of its
    boundary-layer node line (:func:`layer_lines`; one value per line).

    Returns
    -------
    heights : (L,) ndarray
    lines : (L, N + 1) ndarray
        The lines (column 0: the wall node), to say where a height misses; with
        ``whole_lines=False`` only their first element's p + 1 nodes (the same rows: one
        line per wall node), without tracing the lines across the layer.
    """
    p = mesh.order
    layer = mesh.cell_data.get("layer")
    in_layer = np.asarray(layer) == LAYER_BOUNDARY if layer is not None else np.ones(mesh.n_cells, bool)
    lines, _ = layer_lines(mesh.cells, p, mesh.boundary_faces, mesh.boundary_ids, mesh.boundary_cells, in_layer, max_elements=256 if whole_lines else 1)
    if len(lines) == 0:
        return np.zeros(0), lines
    normals = wall_normals(mesh.points, mesh.boundary_faces, mesh.boundary_ids, p)
    step = mesh.points[lines[:, p]] - mesh.points[lines[:, 0]]
    return np.einsum("ij,ij->i", step, normals[lines[:, 0]]), lines


def exact_first_layer(ctx, sm, blocks, height: float, kind: str = "gauss_lobatto") -> None:
    """:func:`place_first_layer` on the transfinite mesh ``sm`` (in place), after the
    optimiser: every boundary-layer line gets its first element ``height`` thick along the
    wall normal. Recorded in the report's ``boundary_layer.placed``; lines given back to keep
    elements valid are named in a warning."""
    in_layer = blocks.block_layer[sm.cell_block] == LAYER_BOUNDARY
    X, info = place_first_layer(sm.points, sm.cells, sm.order, sm.boundary_faces, sm.boundary_ids, sm.boundary_cells, in_layer, height, kind)
    sm.points[:] = X
    ctx.report.sections.setdefault("boundary_layer", {})["placed"] = info
    left = info.get("reverted", 0) + info.get("unplaced", 0)
    if left:
        ctx.warn(
            f"first-layer height: {left} of {info['lines']} boundary-layer lines keep the transfinite spacing "
            f"({info['reverted']} where placing the height would take an element below 0.3 or below the worst element around it, "
            f"{info['unplaced']} sharing nodes with another line, without room for it or too oblique to the wall)"
        )


def offset_to_thickness(ctx, sm, blocks, kind: str = "gauss_lobatto") -> None:
    """With a given total thickness, :func:`~vmesh.geometry.layer_placement.offset_layer` on
    the transfinite mesh ``sm`` (in place), before the optimiser: the layer's inner nodes at
    that thickness from the wall along its normal, so that a wall bulging in between the
    block corners does not cross the layer. Recorded in ``boundary_layer.offset``."""
    section = ctx.report.sections.get("boundary_layer", {})
    thickness = section.get("target_thickness")
    if not thickness:
        return
    layer = blocks.block_layer[sm.cell_block]
    X, info = offset_layer(sm.points, sm.cells, sm.order, sm.boundary_faces, sm.boundary_ids, sm.boundary_cells, layer == LAYER_BOUNDARY,
                           layer == LAYER_RING, thickness, section.get("target_first_height"), kind)
    sm.points[:] = X
    section["offset"] = info
