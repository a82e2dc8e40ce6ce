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

from ..blocks import AXIS_LAYER, HEX_EDGE_AXIS, HEX_EDGES, LAYER_BOUNDARY
from ..errors import MeshingError, ParameterError

#: Metres per length unit.
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}
#: Units an input surface may be given in (``vmesh run --units``).
INPUT_UNITS = ("mm", "cm", "m")
#: Inputs whose bounding-box diagonal is below this are guessed to be in metres, else mm.
METRE_GUESS_BELOW = 2.0

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


def first_cell_heights(mesh) -> np.ndarray:
    """Wall-normal height of the element on each wall face (the first-cell height a CFD
    solver sees): the vector from the wall face's centre to the opposite face's centre,
    projected on the wall face's normal."""
    from ..io.export import boundary_local_faces, face_corner_ids, tensor_faces

    wall = np.flatnonzero(np.asarray(mesh.boundary_ids) == 0)
    if len(wall) == 0:
        return np.zeros(0)
    p = mesh.order
    corners = tensor_faces(p)[:, face_corner_ids(p)]  # (6, 4)
    local = boundary_local_faces(mesh)[wall]
    cells = np.asarray(mesh.cells)[np.asarray(mesh.boundary_cells)[wall]]
    own = mesh.points[np.take_along_axis(cells, corners[local], axis=1)]  # (k, 4, 3)
    opp = mesh.points[np.take_along_axis(cells, corners[local ^ 1], axis=1)]
    normal = np.cross(own[:, 2] - own[:, 0], own[:, 3] - own[:, 1])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    return np.abs(np.einsum("ij,ij->i", opp.mean(axis=1) - own.mean(axis=1), normal))


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
    if bl.first_height is not None:
        out.update(first_layer=bl.first_height, first_layer_absolute=True)
    elif bl.first_relative is not None:
        out["first_layer"] = bl.first_relative / refinement
    elif bl.growth is not None and bl.growth != 1.0:
        out["growth"] = bl.growth ** (1.0 / refinement)
    return out


def first_edge_lengths(mesh) -> np.ndarray:
    """Length of the element edge from each corner of each wall face to the next node off
    the wall (4 per wall face): the first-layer height along the boundary-layer lines."""
    from ..io.export import boundary_local_faces, face_corner_ids, tensor_faces

    wall = np.flatnonzero(np.asarray(mesh.boundary_ids) == 0)
    if len(wall) == 0:
        return np.zeros(0)
    p = mesh.order
    local = boundary_local_faces(mesh)[wall]
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
    h = first_cell_heights(mesh)
    if len(h) == 0:
        return
    section = ctx.report.sections.setdefault("boundary_layer", {})
    section["measured_first_height"] = _stats(h, target)
    section["measured_first_edge"] = _stats(first_edge_lengths(mesh), target)
    nodes, _ = first_node_heights(mesh)
    if len(nodes):
        section["measured_first_node_height"] = _stats(nodes, target)
    ctx.count(first_height=float(np.median(h)))


# ---------------------------------------------------------------------------
# boundary-layer node lines: the exact first-layer height
# ---------------------------------------------------------------------------


def _local_faces(cells: np.ndarray, p: int, faces: np.ndarray, owners: np.ndarray) -> np.ndarray:
    """Local face index (0..5, as :func:`~vmesh.io.export.tensor_faces`) of each boundary
    face (``(k, (p+1)^2)`` node ids) in its owning element, -1 where it is none of them."""
    from ..io.export import face_corner_ids, tensor_faces

    corners = tensor_faces(p)[:, face_corner_ids(p)]  # (6, 4)
    own = np.sort(cells[owners][:, corners], axis=2)  # (k, 6, 4)
    hit = (own == np.sort(faces[:, face_corner_ids(p)], axis=1)[:, None, :]).all(axis=2)
    return np.where(hit.any(axis=1), hit.argmax(axis=1), -1)


def _face_partners(cells: np.ndarray, p: int, members: np.ndarray) -> np.ndarray:
    """For each (member element, local face) pair, flattened as ``6 i + f``, the entry of the
    member that shares the face (-1: none among ``members``)."""
    from ..io.export import face_corner_ids, tensor_faces

    corners = tensor_faces(p)[:, face_corner_ids(p)]
    keys = np.sort(cells[members][:, corners], axis=2).reshape(-1, 4)
    partner = np.full(len(keys), -1, np.int64)
    if len(keys) == 0:
        return partner
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    order = np.argsort(inv.ravel(), kind="stable")
    same = inv.ravel()[order[1:]] == inv.ravel()[order[:-1]]
    a, b = order[:-1][same], order[1:][same]
    partner[a], partner[b] = b, a
    return partner


def layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, in_layer, max_elements=256):
    """The boundary-layer node lines: from every wall node, the nodes of the lattice line
    that leaves the wall across the boundary-layer elements up to the layer's inner face.

    Parameters
    ----------
    cells : (m, (p+1)^3) node ids in tensor order
    p : int
        Element order.
    boundary_faces, boundary_ids, boundary_cells
        As :class:`~vmesh.mesh.HexMesh` (wall: id 0).
    in_layer : (m,) bool
        Elements of the boundary-layer blocks.

    Returns
    -------
    lines : (L, N + 1) int64
        Node ids from the wall node (column 0) inwards, padded with -1 (unique rows).
    elements : (L,) int64
        Elements along each line (its length is ``elements * p + 1``).
    """
    from ..io.export import tensor_faces

    cells = np.asarray(cells)
    wall = np.flatnonzero(np.asarray(boundary_ids) == 0)
    owners = np.asarray(boundary_cells)[wall]
    local = _local_faces(cells, p, np.asarray(boundary_faces)[wall], owners)
    keep = (local >= 0) & in_layer[owners]
    owners, local = owners[keep], local[keep]
    members = np.flatnonzero(in_layer)
    position = np.full(len(cells), -1, np.int64)
    position[members] = np.arange(len(members))
    partner = _face_partners(cells, p, members)
    tf = tensor_faces(p)
    nf = tf.shape[1]
    cell = np.repeat(owners, nf)
    face = np.repeat(local, nf)
    at = np.tile(np.arange(nf), len(owners))
    columns = [cells[cell, tf[face, at]]]
    active = np.ones(len(cell), bool)
    elements = np.zeros(len(cell), np.int64)
    for _ in range(max_elements):
        stride = (p + 1) ** (face // 2) * np.where(face % 2 == 0, 1, -1)
        base = tf[face, at]
        for j in range(1, p + 1):
            columns.append(np.where(active, cells[cell, base + j * stride], -1))
        elements += active
        nxt = partner[6 * np.maximum(position[cell], 0) + (face ^ 1)]
        active &= nxt >= 0
        if not active.any():
            break
        last = columns[-1]
        cell = np.where(active, members[np.maximum(nxt, 0) // 6], cell)
        face = np.where(active, np.maximum(nxt, 0) % 6, face)
        hit = cells[cell[:, None], tf[face]] == last[:, None]
        at = np.where(active, hit.argmax(axis=1), at)
    lines = np.stack(columns, axis=1)
    lines, first = np.unique(lines, axis=0, return_index=True)
    return lines, elements[first]


def wall_normals(points, boundary_faces, boundary_ids, p) -> np.ndarray:
    """(n, 3) unit normals into the vessel at the wall nodes (zero elsewhere): the sum of the
    vector areas of the wall's sub-quadrilaterals (the quads of each face's node lattice)
    around each node, i.e. the area-weighted normal of the wall quads."""
    faces = np.asarray(boundary_faces)[np.asarray(boundary_ids) == 0]
    n = p + 1
    a, b = np.meshgrid(np.arange(p), np.arange(p), indexing="xy")
    q00 = (a + n * b).ravel()
    loop = np.stack([q00, q00 + 1, q00 + 1 + n, q00 + n], axis=1)  # (p^2, 4), outward like the face
    quads = faces[:, loop].reshape(-1, 4)
    x = points[quads]
    area = 0.5 * np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])
    out = np.zeros((len(points), 3))
    for c in range(4):
        np.add.at(out, quads[:, c], -area)  # outward face normals: into the vessel is minus
    norm = np.linalg.norm(out, axis=1)
    return np.divide(out, norm[:, None], out=np.zeros_like(out), where=norm[:, None] > 0)


def cap_normals(points, boundary_faces, boundary_ids, p) -> np.ndarray:
    """(n, 3) unit normal of the cap plane (inlet or outlet face set) at each of its nodes,
    zero elsewhere."""
    out = np.zeros((len(points), 3))
    faces, ids = np.asarray(boundary_faces), np.asarray(boundary_ids)
    corners = faces[:, [0, p, (p + 1) ** 2 - 1, p * (p + 1)]]
    for bid in np.unique(ids[ids > 0]):  # a few open ends
        sel = ids == bid
        q = points[corners[sel]]
        normal = np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]).sum(axis=0)
        out[np.unique(faces[sel])] = normal / max(np.linalg.norm(normal), 1e-300)
    return out


def _ratios(r: np.ndarray, n: int) -> np.ndarray:
    """Growth ratios q with ``1 + q + ... + q**(n-1) = r`` (vectorised bisection on log q)."""
    lo = np.full(len(r), -20.0 / max(n, 1))
    hi = np.full(len(r), 20.0 / max(n - 1, 1))
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        small = np.abs(mid) < 1e-12
        s = np.where(small, float(n), np.expm1(n * mid) / np.where(small, 1.0, np.expm1(mid)))
        below = s < r
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.exp(0.5 * (lo + hi))


def _graded_curve(x0, d, xn, first, n, p, kind, samples=48):
    """Nodes of lines from ``x0`` to ``xn`` leaving ``x0`` along ``d`` (a quadratic Bézier
    curve tangent to ``d``), spaced by arc length as ``n`` elements of order ``p`` whose
    first is ``first`` long (then straight along ``d``, so its far node is exactly at
    ``x0 + first d``) and the rest grow geometrically to the end."""
    from .transfinite import element_boundaries, with_order

    ctrl = x0 + 0.5 * np.einsum("ij,ij->i", xn - x0, d)[:, None] * d
    s = np.linspace(0.0, 1.0, samples)[None, :, None]
    curve = (1 - s) ** 2 * x0[:, None] + 2 * s * (1 - s) * ctrl[:, None] + s**2 * xn[:, None]
    arc = np.concatenate([np.zeros((len(x0), 1)), np.cumsum(np.linalg.norm(np.diff(curve, axis=1), axis=2), axis=1)], axis=1)
    total = arc[:, -1]
    q = _ratios(total / first, n)
    u = with_order(element_boundaries(n, q), p, kind) * total[:, None]  # (L, n p + 1)
    # the arc-length targets on the sampled polyline, row by row
    k = np.clip((arc[:, None, :] <= u[:, :, None]).sum(axis=2) - 1, 0, samples - 2)
    a0, a1 = np.take_along_axis(arc, k, 1), np.take_along_axis(arc, k + 1, 1)
    w = np.clip((u - a0) / np.maximum(a1 - a0, 1e-300), 0.0, 1.0)[..., None]
    c0 = np.take_along_axis(curve, k[..., None], 1)
    c1 = np.take_along_axis(curve, k[..., None] + 1, 1)
    out = c0 + w * (c1 - c0)
    out[:, : p + 1] = x0[:, None] + u[:, : p + 1, None] * d[:, None]
    out[:, -1] = xn
    return out


def _line_directions(X, lines, normals, caps, p):
    """Two directions for the first element of each line, and the lines left as they are.

    ``d``: the wall normal, except at a wall node with several lines (where layer blocks of
    different orientation meet): the line's own first edge, so that the lines stay apart.
    ``own``: the line's own first edge (the fallback where ``d`` would spoil an element). On
    a cap (inlet/outlet rim) both keep only their component in the cap plane, so that the
    cap stays plane. ``shared``: lines with a node (besides their inner end) on another line."""
    x0 = X[lines[:, 0]]
    wall_node, count = np.unique(lines[:, 0], return_counts=True)
    several = np.isin(lines[:, 0], wall_node[count > 1])
    own = X[lines[:, p]] - x0
    c = caps[lines[:, 1]]
    out = []
    for d in (np.where(several[:, None], own, normals[lines[:, 0]]), own):
        d = d - np.einsum("ij,ij->i", d, c)[:, None] * c
        out.append(d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None])
    inner = lines[:, 1:-1]
    ids, counts = np.unique(inner[inner >= 0], return_counts=True)
    shared = np.isin(lines[:, 1:], ids[counts > 1]).any(axis=1)
    return out[0], out[1], several, shared


def _placed(X0, lines, elements, d, n0, height, p, kind, first_only=False):
    """Node positions with every line whose first element can be ``height`` thick along the
    wall normal ``n0`` when it leaves the wall along ``d`` re-placed, and which lines those
    are: the whole line (:func:`_graded_curve`), or with ``first_only`` the first element
    alone (its far node moves along ``d``; the rest of the line stays)."""
    cos = np.einsum("ij,ij->i", d, n0)
    first = height / np.maximum(cos, 1e-3)
    end = np.minimum(np.where(first_only, 2, elements), elements) * p
    x0 = X0[lines[:, 0]]
    reach = np.einsum("ij,ij->i", X0[lines[np.arange(len(lines)), end]] - x0, d)
    ok = (cos > 0.5) & (elements >= (2 if first_only else 1)) & (reach > first * 1.01)
    X = X0.copy()
    if first_only:
        from .transfinite import reference_points

        t = reference_points(p, kind)[1:]  # the first element's nodes off the wall, along d
        sel = np.flatnonzero(ok)
        X[lines[sel, 1 : p + 1]] = x0[sel, None] + (first[sel, None] * t[None, :])[..., None] * d[sel, None]
        return X, ok
    for n in np.unique(elements[ok]):
        sel = np.flatnonzero(ok & (elements == n))
        ids = lines[sel, : n * p + 1]
        X[ids[:, 1:-1]] = _graded_curve(X0[ids[:, 0]], d[sel], X0[ids[:, -1]], first[sel], int(n), p, kind)[:, 1:-1]
    return X, ok


def place_first_layer(points, cells, p, boundary_faces, boundary_ids, boundary_cells, in_layer, height, kind="gauss_lobatto", floor=0.3):
    """Re-place the nodes of every boundary-layer node line so that its first element is
    ``height`` thick along the wall normal and the others grow geometrically to the layer's
    inner node (which, like the wall node, stays).

    The first node off the wall goes to ``x0 + height d / (d . n)`` (``n`` the area-weighted
    wall normal, ``d`` the line's first direction, see :func:`_line_directions`): its
    wall-normal distance is exactly ``height``. Where that would lower an element's scaled
    Jacobian below ``min(before, floor)``, the line of that element whose first node moved
    farthest steps back: to its first element alone re-placed (the rest of the line as the
    optimiser left it), then along its own first direction (the same wall-normal height, a
    longer first edge), then to its spacing as it was; repeated until no element does.

    Returns
    -------
    X : (n, 3) ndarray
        The new node positions.
    info : dict
        Line counts: ``lines``, ``placed`` (along the normal), ``first_element_only`` and
        ``own_direction`` (the fallbacks), ``reverted`` (unchanged to keep elements valid), ``unplaced`` (unchanged:
        shared nodes, no room or too oblique), ``several`` (at wall nodes with several lines);
        the minimum scaled Jacobian of the touched elements before and after.
    """
    from .quality import scaled_jacobian
    from .transfinite import reference_points

    X0 = np.asarray(points, float)
    cells = np.asarray(cells)
    lines, elements = layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, np.asarray(in_layer, bool))
    if len(lines) == 0:
        return X0.copy(), {"lines": 0}
    normals = wall_normals(X0, boundary_faces, boundary_ids, p)
    d, own, several, shared = _line_directions(X0, lines, normals, cap_normals(X0, boundary_faces, boundary_ids, p), p)
    n0 = normals[lines[:, 0]]
    # the tiers a line steps through: the whole line from the wall normal, its first element
    # alone along the normal, then along its own direction, then as it was
    tiers = [_placed(X0, lines, elements, d, n0, height, p, kind), _placed(X0, lines, elements, d, n0, height, p, kind, True),
             _placed(X0, lines, elements, own, n0, height, p, kind, True), (X0, np.ones(len(lines), bool))]
    last = len(tiers) - 1
    possible = np.stack([t[1] & ~shared for t in tiers[:-1]] + [np.ones(len(lines), bool)], axis=1)
    tier = possible.argmax(axis=1)
    X = X0.copy()
    for k in range(last):
        nodes = lines[tier == k, 1:]
        X[nodes[nodes >= 0]] = tiers[k][0][nodes[nodes >= 0]]
    # the line of each moving node (not its wall node or inner end), to step lines back
    line_of = np.full(len(X), -1, np.int64)
    mid = lines[:, 1:].copy()
    mid[np.arange(len(lines)), elements * p - 1] = -1
    has = mid >= 0
    line_of[mid[has]] = np.broadcast_to(np.arange(len(lines))[:, None], mid.shape)[has]
    touched = np.flatnonzero((line_of[cells] >= 0).any(axis=1))
    ref = reference_points(p, kind)
    before = scaled_jacobian(X0, cells[touched], p, ref)
    # an element may drop to the worst element its lines touch (so that a line through a fold
    # can unfold it at some cost to its neighbours), never below floor otherwise, nor fold
    on = line_of[cells[touched]]
    worst_of_line = np.full(len(lines), np.inf)
    np.minimum.at(worst_of_line, on[on >= 0], np.broadcast_to(before[:, None], on.shape)[on >= 0])
    allowed = np.where(on >= 0, worst_of_line[np.maximum(on, 0)], np.inf).min(axis=1)
    allowed = np.minimum(np.minimum(allowed, floor), before)
    start = tier.copy()
    for _ in range(100):
        after = scaled_jacobian(X, cells[touched], p, ref)
        bad = touched[(after < allowed) | ((after <= 0) & (after < before))]
        # in each bad element, the line whose first node moved farthest steps back a tier
        on = line_of[cells[bad]]
        moved = np.where(on >= 0, np.linalg.norm(X[lines[np.maximum(on, 0), p]] - X0[lines[np.maximum(on, 0), p]], axis=-1), -1.0)
        moved[(on >= 0) & (tier[np.maximum(on, 0)] == last)] = -1.0
        pick = np.take_along_axis(on, moved.argmax(axis=1)[:, None], 1)[:, 0]
        back = np.unique(pick[moved.max(axis=1) >= 0]) if len(bad) else pick
        if len(back) == 0:
            break
        later = possible[back] & (np.arange(last + 1)[None, :] > tier[back][:, None])
        tier[back] = later.argmax(axis=1)
        nodes = lines[back, 1:]  # back to as it was, then to the new tier
        X[nodes[nodes >= 0]] = X0[nodes[nodes >= 0]]
        for k in range(1, last):
            nodes = lines[back[tier[back] == k], 1:]
            X[nodes[nodes >= 0]] = tiers[k][0][nodes[nodes >= 0]]
    info = {"lines": len(lines), "placed": int((tier == 0).sum()), "first_element_only": int((tier == 1).sum()), "own_direction": int((tier == 2).sum()),
            "reverted": int(((tier == last) & (start < last)).sum()), "unplaced": int((start == last).sum()), "several": int(several.sum()),
            "sj_before": float(before.min()) if len(touched) else None, "sj_after": float(after.min()) if len(touched) else None}
    return X, info


def first_node_heights(mesh) -> tuple[np.ndarray, np.ndarray]:
    """The first-layer height at each wall node: the distance, along the wall normal
    (:func:`wall_normals`), from the wall node to the first element corner of its
    boundary-layer node line (:func:`layer_lines`; one value per line).

    Returns
    -------
    heights : (L,) ndarray
    lines : (L, N + 1) ndarray
        The lines (column 0: the wall node), to say where a height misses.
    """
    p = mesh.order
    layer = mesh.cell_data.get("layer")
    in_layer = np.asarray(layer) == LAYER_BOUNDARY if layer is not None else np.ones(mesh.n_cells, bool)
    lines, _ = layer_lines(mesh.cells, p, mesh.boundary_faces, mesh.boundary_ids, mesh.boundary_cells, in_layer)
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
            f"({info['reverted']} where placing the height would lower an element's scaled Jacobian below min(before, 0.3), "
            f"{info['unplaced']} sharing nodes with another line, without room for it or too oblique to the wall)"
        )
