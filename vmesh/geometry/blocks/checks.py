"""Checks of block structures: wall-projected and filled quality, invalid blocks written out,
and the failure raised when blocks stay invalid."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...blocks import FACE_INTERIOR, FACE_WALL, HEX_FACES, BlockStructure
from ...errors import MeshingError


def projected_wall_quality(blocks: BlockStructure, project, samples: int = 4, last: dict | None = None) -> np.ndarray:
    # duplicates: its docstring's parameter list reads like transfinite.mesh_blocks'; no shared logic
    """Scaled Jacobian of boundary-layer blocks once their wall faces are projected onto the wall.

    The wall face of every block with a wall face is sampled bilinearly on a
    ``samples × samples`` grid and projected with ``project``; the sub-hexahedra between
    the projected wall grid and the matching grid on the opposite face must stay valid, or
    the meshed boundary layer will fold there (the wall bulging through the layer).

    Parameters
    ----------
    blocks : BlockStructure
    project : callable
        ``project(points (n, 3)) -> closest wall points (n, 3)``.
    samples : int
        Sub-faces per side of a wall face.
    last : dict, optional
        The previous call's faces and results with the same ``project`` (filled in here;
        start with ``{}``): faces whose eight corners are where they were keep their result
        (each face's value depends on its corners alone), so a fix that moves a few sections
        of a tree projects only their blocks' faces again.

    Returns
    -------
    (nb,) float: the smallest scaled corner Jacobian per block (1 for blocks off the wall).
    """
    out = np.ones(blocks.n_blocks)
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    # faces 0..3 (i, j sides): the opposite face across the layer; end faces (k) are skipped
    keep = f < 4
    b, f = b[keep], f[keep]
    if len(b) == 0:
        return out
    wall = blocks.vertices[blocks.hexes[b[:, None], HEX_FACES[f]]]  # (m, 4, 3), outward order
    # the opposite face in the same corner order: reversed orientation, matched corner by corner
    inner = blocks.vertices[blocks.hexes[b[:, None], _OPPOSITE[f]]]
    corners = np.concatenate([wall, inner], axis=1)  # (m, 8, 3)
    if last is not None and last.get("samples") == samples and np.array_equal(last.get("faces"), np.c_[b, f]):
        redo = np.flatnonzero(np.any(corners != last["corners"], axis=(1, 2)))
        sj = last["sj"].copy()
        sj[redo] = _face_quality(wall[redo], inner[redo], project, samples)
    else:
        sj = _face_quality(wall, inner, project, samples)
    if last is not None:
        last.update(samples=samples, faces=np.c_[b, f], corners=corners, sj=sj)
    np.minimum.at(out, b, sj)
    return out


def wall_left_out(blocks: BlockStructure, project, points: np.ndarray, radii: np.ndarray, samples: int = 8) -> np.ndarray:
    """How far wall ``points`` stand from the blocks' wall, × ``radii``: the mesh's wall as
    the wall faces sampled bilinearly on a ``samples × samples`` grid and projected onto the
    wall with ``project`` (as the mesher puts its wall nodes), so that only wall the blocks
    cut across (a corner of the vessel between two of their faces) counts, not the faces'
    sag. Only the faces within their own size and the largest radius of the points'
    bounding box are sampled."""
    from ..bvh import TriangleBVH

    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    quads = blocks.vertices[blocks.hexes[b[:, None], HEX_FACES[f]]]  # (m, 4, 3)
    lo, hi = points.min(axis=0), points.max(axis=0)
    reach = np.linalg.norm(quads - quads.mean(axis=1, keepdims=True), axis=2).max(axis=1) + radii.max()
    near = np.all((quads.min(axis=1) <= hi + reach[:, None]) & (quads.max(axis=1) >= lo - reach[:, None]), axis=1)
    quads = quads[near]
    if len(quads) == 0:
        return np.full(len(points), np.inf)
    grid = np.asarray(project(np.einsum("abc,mcd->mabd", _bilinear_weights(samples), quads).reshape(-1, 3)))
    k = np.arange((samples + 1) ** 2).reshape(samples + 1, samples + 1)
    corner = [k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()]
    tri = np.r_[np.c_[corner[0], corner[1], corner[2]], np.c_[corner[0], corner[2], corner[3]]]
    tri = (tri[None] + (np.arange(len(quads)) * (samples + 1) ** 2)[:, None, None]).reshape(-1, 3)
    sq = TriangleBVH(grid, tri).closest(points)[0]
    return np.sqrt(sq) / radii


def _bilinear_weights(samples: int) -> np.ndarray:
    """(n+1, n+1, 4) weights of a quad's four corners on a ``samples × samples`` grid."""
    s = np.linspace(0.0, 1.0, samples + 1)
    U, V = np.meshgrid(s, s, indexing="ij")
    return np.stack([(1 - U) * (1 - V), U * (1 - V), U * V, (1 - U) * V], axis=-1)


#: per wall face (0..3) of a block, the opposite face's corners matched to its own
_OPPOSITE = np.array([[1, 5, 6, 2], [0, 3, 7, 4], [3, 2, 6, 7], [0, 4, 5, 1]])


def _face_quality(wall: np.ndarray, inner: np.ndarray, project, samples: int) -> np.ndarray:
    """Smallest scaled corner Jacobian of the layer between each wall face ``(m, 4, 3)``,
    sampled and projected onto the wall, and its opposite face ``(m, 4, 3)``."""
    from ...blocks import scaled_corner_jacobians

    if len(wall) == 0:
        return np.zeros(0)
    w = _bilinear_weights(samples)
    outer_grid = np.einsum("abc,mcd->mabd", w, wall)
    inner_grid = np.einsum("abc,mcd->mabd", w, inner)
    shape = outer_grid.shape
    outer_grid = np.asarray(project(outer_grid.reshape(-1, 3))).reshape(shape)
    o, i = outer_grid, inner_grid
    # sub-hexes: bottom = inner cell, top = projected wall cell (outward along the layer)
    H = np.stack([i[:, :-1, :-1], i[:, 1:, :-1], i[:, 1:, 1:], i[:, :-1, 1:],
                  o[:, :-1, :-1], o[:, 1:, :-1], o[:, 1:, 1:], o[:, :-1, 1:]], axis=3)
    sj = scaled_corner_jacobians(H.reshape(-1, 8, 3)).min(axis=1).reshape(len(wall), -1)
    # wall corners run outward: the inner cell (bottom) faces the projected wall (top)
    return sj.min(axis=1)


#: Element counts of the fill checks (around, ring, layer, element length × radius, refinement
#: dividing the first layer): the default chain's, and a finer one as at vascularmd's resolution.
FILL_CHECKS = ((2, 2, 3, 0.5, 1), (4, 3, 4, 0.25, 2))


def fill_quality(blocks: BlockStructure, subset: np.ndarray, project, distance, intersect_lines=None, refinement=None,
                 per_resolution: bool = False) -> np.ndarray:
    """Least scaled Jacobian of each block of ``subset`` once filled with hexahedra.

    The blocks are filled as :func:`~vmesh.geometry.transfinite.mesh_blocks` fills them
    (edges and faces on the wall projected, transfinite interiors), without any untangling,
    at each resolution of ``refinement`` (default :data:`FILL_CHECKS`: the default chain's
    and a finer one); the least over them counts. This, not the blocks' corners, decides
    whether a junction's blocks map validly.

    Parameters
    ----------
    blocks : BlockStructure
    subset : (k,) int
        Blocks to fill (shared edges and faces are filled as in the whole structure).
    project, distance, intersect_lines : callable
        As for :func:`~vmesh.geometry.transfinite.mesh_blocks`.
    refinement : sequence of (around, ring, layer, element_length, first-layer divisor), optional
    per_resolution : bool
        Return one row per resolution instead of combining them.

    Returns
    -------
    (k,) float (``(len(refinement), k)`` with ``per_resolution``): the least scaled Jacobian
    of each block's elements, or, where some are inverted, minus the share of its elements
    inverted less the mean of ``min(0, scaled Jacobian)`` (summed over the resolutions).
    """
    subset = np.asarray(subset, np.int64)
    refs = refinement or FILL_CHECKS
    if len(subset) == 0:
        return np.ones((len(refs), 0)) if per_resolution else np.ones(0)
    out = np.ones((len(refs), len(subset)))
    folded = np.zeros((len(refs), len(subset)))
    for r, (sm, sj) in enumerate(filled(blocks, subset, project, distance, intersect_lines, refs)):
        np.minimum.at(out[r], sm.cell_block, sj)
        # per element of the block at this resolution: each resolution weighs the same
        # each inverted element counts one, less its scaled Jacobian: fewer folds first, then shallower
        np.add.at(folded[r], sm.cell_block, (np.minimum(sj, 0.0) - (sj <= 0)) / np.prod(sm.block_counts, axis=1)[sm.cell_block])
    # a folded block scores minus the share of its elements inverted (less their scaled
    # Jacobians): fewer and shallower folds score higher, any fold lower than every valid block
    if per_resolution:
        return np.where(folded < 0, folded, out)
    return np.where(folded.sum(axis=0) < 0, folded.sum(axis=0), out.min(axis=0))


def filled(blocks: BlockStructure, subset: np.ndarray, project, distance, intersect_lines=None, refinement=None):
    """Per resolution of ``refinement`` (default :data:`FILL_CHECKS`) the blocks ``subset``
    filled as :func:`fill_quality` fills them, and each element's scaled Jacobian: pairs
    ``(StructuredMesh, (n,) float)``, ``cell_block`` indexing ``subset``."""
    from ..quality import hex8_scaled_jacobian
    from ..transfinite import Refinement, mesh_blocks

    # only the subset's vertices: the mesher projects every wall vertex it is given
    used, hexes = np.unique(blocks.hexes[subset], return_inverse=True)
    sub = BlockStructure(
        vertices=blocks.vertices[used], hexes=hexes.reshape(-1, 8), vertex_on_surface=blocks.vertex_on_surface[used],
        face_boundary=blocks.face_boundary[subset], axis_kind=blocks.axis_kind[subset],
        block_radius=blocks.block_radius[subset], block_node=blocks.block_node[subset],
        block_segment=blocks.block_segment[subset], block_layer=blocks.block_layer[subset],
        boundary_names=dict(blocks.boundary_names),
    )
    for counts in refinement or FILL_CHECKS:
        ref = Refinement(around=counts[0], core=counts[0], ring=counts[1], layer=counts[2], element_length=counts[3], first_layer=0.02 / counts[4])
        sm = mesh_blocks(sub, project, ref, signed_distance=distance, intersect_lines=intersect_lines)
        yield sm, hex8_scaled_jacobian(sm.points, sm.cells)


def fill_score(quality: np.ndarray) -> float:
    """One number for a set of blocks' :func:`fill_quality`: the least value when all are
    valid, else the sum over the folded blocks (always below any valid set's)."""
    quality = np.asarray(quality, float)
    neg = quality[quality < 0]
    return float(neg.sum()) if len(neg) else float(quality.min(initial=1.0))


def write_bad_blocks(blocks: BlockStructure, bad: np.ndarray, path) -> Path:
    """Write the given blocks (with their neighbours for context) to a VTU file."""
    from ...io.atomic import atomic_path

    path = Path(path)
    grid = blocks.to_pyvista()
    bad = np.asarray(bad)
    mark = np.zeros(blocks.n_blocks, np.uint8)
    mark[bad] = 1
    grid.cell_data["invalid"] = mark
    # the invalid blocks and every block touching them
    touch = np.isin(blocks.hexes, blocks.hexes[bad]).any(axis=1)
    sub = grid.extract_cells(np.flatnonzero(touch))
    with atomic_path(path) as tmp:
        sub.save(str(tmp), binary=True)
    return path


def block_structure_checks(blocks: BlockStructure) -> dict:
    """Topological checks of a block structure.

    Returns
    -------
    dict with
        ``invalid_blocks``: blocks with a non-positive corner Jacobian;
        ``min_corner_jacobian``: the smallest corner Jacobian;
        ``face_use_errors``: unique faces used by more than two blocks, interior faces used
        by one block, or boundary faces used by two;
        ``boundary_quads``: number of outer faces (wall and open ends);
        ``boundary_components``: connected pieces of the outer quad surface;
        ``boundary_euler``: its Euler characteristic V - E + F;
        ``nonmanifold_boundary_edges``: outer edges not shared by exactly two outer quads;
        ``block_components``: connected pieces of blocks sharing faces.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    H = blocks.hexes
    nb = len(H)
    faces = H[:, HEX_FACES].reshape(-1, 4)
    key = np.sort(faces, axis=1)
    uniq, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    fb = blocks.face_boundary.reshape(-1)
    use = count[inv]
    errors = int(np.sum(count > 2)) + int(np.sum((fb == FACE_INTERIOR) & (use != 2))) + int(np.sum((fb != FACE_INTERIOR) & (use != 1)))
    # block adjacency through shared faces
    owner = np.repeat(np.arange(nb), 6)
    order = np.argsort(inv, kind="stable")
    same = inv[order][1:] == inv[order][:-1]
    a, b = owner[order][:-1][same], owner[order][1:][same]
    adj = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(nb, nb))
    n_blocks_comp = connected_components(adj, directed=False)[0] if nb else 0
    quads, _ = blocks.boundary_quads()
    edges = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    ue, ecount = np.unique(edges, axis=0, return_counts=True)
    qv = np.unique(quads)
    n_comp = 0
    if len(quads):
        qi = np.repeat(np.arange(len(quads)), 4)
        vid = np.searchsorted(qv, quads.reshape(-1))
        inc = sp.coo_matrix((np.ones(len(qi)), (qi, vid)), shape=(len(quads), len(qv))).tocsr()
        n_comp = connected_components(inc @ inc.T, directed=False)[0]
    J = blocks.corner_jacobians()
    return {
        "invalid_blocks": int(np.sum(J.min(axis=1) <= 0)),
        "min_corner_jacobian": float(J.min()) if nb else 0.0,
        "face_use_errors": errors,
        "boundary_quads": int(len(quads)),
        "boundary_components": int(n_comp),
        "boundary_euler": int(len(qv) - len(ue) + len(quads)),
        "nonmanifold_boundary_edges": int(np.sum(ecount != 2)),
        "block_components": int(n_blocks_comp),
    }


class _Failure(Exception):
    """Blocks that stay invalid, with what a changed skeleton might fix."""

    def __init__(self, message, blocks, bad, skeleton, nfurcations, crowded, hint):
        super().__init__(message)
        self.message, self.blocks, self.bad = message, blocks, bad
        self.skeleton, self.nfurcations, self.crowded, self.hint = skeleton, nfurcations, crowded, hint
        self.stubs = []  # side-branch stubs too short for a block (:mod:`.stubs`)
        self.leaned = False  # some n-furcation's half-sections leaned (:meth:`_Junctions._leaned`)
        self.bends = []  # nodes whose crossing sections straightening could not part (:mod:`.crossings`)

    def error(self, path, tries: int = 1) -> MeshingError:
        written = ""
        if path is not None and self.blocks is not None:
            try:
                written = f"; the {len(self.bad)} invalid block(s) are in {write_bad_blocks(self.blocks, self.bad, path)}"
            except Exception as exc:  # the error itself matters more than the picture
                written = f" (could not write the invalid blocks: {exc})"
        tried = f" ({tries - 1} changed skeleton(s) tried too)" if tries > 1 else ""
        return MeshingError(self.message + written + tried + self.hint)
