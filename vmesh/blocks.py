"""The block structure: a coarse, conforming set of hexahedral blocks.

This module holds the plain data class shared by the block-structure stage
(which builds it) and the transfinite stage (which fills every block with
elements). Local conventions follow VTK's linear hexahedron.

Corner ``c`` of a block has local coordinates ``HEX_CORNERS[c]`` in ``{0,1}^3``
(axes i, j, k); corners 0-3 are the k=0 face and 4-7 lie above them. Blocks are
right-handed: the Jacobian is positive at every corner.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: local (i, j, k) coordinates of the 8 corners, VTK order
HEX_CORNERS = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=np.int64
)
#: the 6 faces as corner indices, outward-oriented: i=0, i=1, j=0, j=1, k=0, k=1
HEX_FACES = np.array(
    [[0, 4, 7, 3], [1, 2, 6, 5], [0, 1, 5, 4], [3, 7, 6, 2], [0, 3, 2, 1], [4, 5, 6, 7]], dtype=np.int64
)
#: the 12 edges as (corner, corner) pairs, grouped by the axis they run along (4 per axis: i, j, k)
HEX_EDGES = np.array(
    [[0, 1], [3, 2], [4, 5], [7, 6], [0, 3], [1, 2], [4, 7], [5, 6], [0, 4], [1, 5], [3, 7], [2, 6]], dtype=np.int64
)
HEX_EDGE_AXIS = np.repeat(np.arange(3), 4)

# kinds of block axes: how the transfinite stage chooses element counts along them
AXIS_ALONG = 0  #: along the skeleton (element length relative to the local radius)
AXIS_AROUND = 1  #: around the circumference
AXIS_CORE = 2  #: across the inner core square
AXIS_RING = 3  #: radially across the ring between core and boundary layer
AXIS_LAYER = 4  #: radially across the boundary layer (graded towards the wall)
AXIS_KIND_NAMES = {AXIS_ALONG: "along", AXIS_AROUND: "around", AXIS_CORE: "core", AXIS_RING: "ring", AXIS_LAYER: "layer"}

LAYER_CORE, LAYER_RING, LAYER_BOUNDARY = 0, 1, 2
LAYER_NAMES = {LAYER_CORE: "core", LAYER_RING: "ring", LAYER_BOUNDARY: "boundary_layer"}

FACE_INTERIOR = -1  #: face shared with another block
FACE_WALL = 0  #: face on the vessel wall (projected onto the surface)
# face ids >= 1 are open ends (inlet/outlet caps), named in BlockStructure.boundary_names


@dataclass
class BlockStructure:
    """A conforming hexahedral block structure of a vessel.

    Attributes
    ----------
    vertices : (nv, 3) float64
        Block corners; corners on the wall lie on the surface.
    hexes : (nb, 8) int64
        Corner indices per block (VTK hexahedron order, positive Jacobian).
    vertex_on_surface : (nv,) bool
        Corner lies on the vessel wall.
    face_boundary : (nb, 6) int64
        Per local face (:data:`HEX_FACES` order): -1 interior, 0 wall, k >= 1 open end k.
    axis_kind : (nb, 3) int64
        Kind of each local axis i, j, k (``AXIS_*``), for element counts.
    block_radius : (nb,) float64
        Local vessel radius (mm), scales element sizes.
    block_node : (nb,) int64
        Skeleton node whose cross-section the block starts from.
    block_segment : (nb,) int64
        Skeleton edge the block lies along (-1 inside a junction).
    block_layer : (nb,) int64
        ``LAYER_CORE``, ``LAYER_RING`` or ``LAYER_BOUNDARY``.
    block_tags : list of tuple of str
        Semantic tags inherited from the skeleton.
    boundary_names : dict int -> str
        ``{0: "wall", 1: "inlet", 2: "outlet_1", ...}``.
    """

    vertices: np.ndarray
    hexes: np.ndarray
    vertex_on_surface: np.ndarray
    face_boundary: np.ndarray
    axis_kind: np.ndarray
    block_radius: np.ndarray
    block_node: np.ndarray
    block_segment: np.ndarray
    block_layer: np.ndarray
    block_tags: list = field(default_factory=list)
    boundary_names: dict = field(default_factory=lambda: {FACE_WALL: "wall"})
    #: free-form diagnostics (twist angles, fixes applied...)
    info: dict = field(default_factory=dict)

    def __repr__(self) -> str:  # counts, not the arrays
        return f"BlockStructure({len(self.hexes)} blocks, {len(self.vertices)} corners, boundaries {list(self.boundary_names.values())})"

    def __post_init__(self):
        self.vertices = np.asarray(self.vertices, np.float64).reshape(-1, 3)
        self.hexes = np.asarray(self.hexes, np.int64).reshape(-1, 8)
        nb = len(self.hexes)
        self.vertex_on_surface = np.asarray(self.vertex_on_surface, bool).reshape(-1)
        self.face_boundary = np.asarray(self.face_boundary, np.int64).reshape(nb, 6)
        self.axis_kind = np.asarray(self.axis_kind, np.int64).reshape(nb, 3)
        for name in ("block_radius", "block_node", "block_segment", "block_layer"):
            arr = np.asarray(getattr(self, name)).reshape(-1)
            if len(arr) != nb:
                raise ValueError(f"BlockStructure.{name} has {len(arr)} entries for {nb} blocks")
            setattr(self, name, arr.astype(np.float64 if name == "block_radius" else np.int64))
        self.block_tags = [tuple(t) for t in self.block_tags] or [()] * nb

    @property
    def n_blocks(self) -> int:
        return len(self.hexes)

    def corner_jacobians(self) -> np.ndarray:
        """(nb, 8) determinant of the trilinear map's Jacobian at each corner."""
        return hex_corner_jacobians(self.vertices[self.hexes])

    def wall_faces(self) -> np.ndarray:
        """(nf, 4) corner indices of the block faces on the wall."""
        b, f = np.nonzero(self.face_boundary == FACE_WALL)
        return self.hexes[b[:, None], HEX_FACES[f]]

    def boundary_quads(self) -> tuple[np.ndarray, np.ndarray]:
        """All outer block faces ``(nf, 4)`` and their boundary id (0 wall, k open end k)."""
        b, f = np.nonzero(self.face_boundary != FACE_INTERIOR)
        return self.hexes[b[:, None], HEX_FACES[f]], self.face_boundary[b, f]

    def surface_edges(self) -> np.ndarray:
        """Unique corner pairs of block edges lying on the wall."""
        q = self.wall_faces()
        e = np.sort(np.stack([q, np.roll(q, -1, axis=1)], -1).reshape(-1, 2), axis=1)
        return np.unique(e, axis=0)

    def cell_arrays(self) -> dict[str, np.ndarray]:
        """Per-block arrays of the block files: ids, segment, node, layer, least corner Jacobian."""
        return {
            "block_id": np.arange(self.n_blocks),
            "segment_id": self.block_segment,
            "node_id": self.block_node,
            "layer": self.block_layer,
            "min_corner_jacobian": self.corner_jacobians().min(axis=1),
        }

    def to_pyvista(self):
        """An UnstructuredGrid of the blocks with per-block data (for ParaView/VTU)."""
        import pyvista as pv

        cells = np.hstack([np.full((self.n_blocks, 1), 8), self.hexes]).ravel()
        grid = pv.UnstructuredGrid(cells, np.full(self.n_blocks, pv.CellType.HEXAHEDRON, np.uint8), self.vertices)
        for name, values in self.cell_arrays().items():
            grid.cell_data[name] = values
        grid.point_data["on_surface"] = self.vertex_on_surface.astype(np.uint8)
        return grid


def hex_corner_jacobians(corners: np.ndarray) -> np.ndarray:
    """Jacobian determinants at the corners of trilinear hexahedra.

    Parameters
    ----------
    corners : (..., 8, 3) array in VTK order.

    Returns
    -------
    (..., 8) array; at each corner, the triple product of the three edges leaving it
    along +i, +j, +k (sign-adjusted so a right-handed block is positive everywhere).
    """
    c = np.asarray(corners, float)
    ijk = HEX_CORNERS.tolist()
    out = np.empty(c.shape[:-1])
    # one corner at a time: (..., 3) temporaries instead of (..., 8, 3, 3) (the block
    # builder checks every block of a tree once per fix round)
    for n, v in enumerate(ijk):
        e = []
        for a in range(3):  # the edge to the neighbour along axis a, pointing to +a
            w = list(v)
            w[a] = 1 - w[a]
            step = c[..., ijk.index(w), :] - c[..., n, :]
            e.append(step if v[a] == 0 else -step)
        out[..., n] = np.einsum("...i,...i->...", e[0], np.cross(e[1], e[2]))
    return out


def scaled_corner_jacobians(corners: np.ndarray) -> np.ndarray:
    """Scaled Jacobians (Jacobian / product of edge lengths) at the 8 corners, in [-1, 1]."""
    c = np.asarray(corners, float)
    j = hex_corner_jacobians(c)
    ijk = HEX_CORNERS
    idx = {tuple(v): n for n, v in enumerate(ijk.tolist())}
    lengths = np.ones(j.shape)
    for n, v in enumerate(ijk.tolist()):
        for a in range(3):
            w = list(v)
            w[a] = 1 - w[a]
            lengths[..., n] *= np.linalg.norm(c[..., idx[tuple(w)], :] - c[..., n, :], axis=-1)
    return j / np.maximum(lengths, 1e-300)
