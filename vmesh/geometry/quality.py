"""Element quality: scaled Jacobians of (high-order) hexahedra."""

from __future__ import annotations

import numba as nb
import numpy as np


def lagrange_derivative_matrix(nodes: np.ndarray) -> np.ndarray:
    """D[a, b] = derivative of the b-th 1-D Lagrange basis function at node a."""
    x = np.asarray(nodes, float)
    diff = x[:, None] - x[None, :]
    np.fill_diagonal(diff, 1.0)
    w = 1.0 / np.prod(diff, axis=1)  # barycentric weights
    D = (w[None, :] / w[:, None]) / diff
    np.fill_diagonal(D, 0.0)
    np.fill_diagonal(D, -D.sum(axis=1))
    return D


def scaled_jacobian(points: np.ndarray, cells: np.ndarray, order: int = 1, ref_nodes: np.ndarray | None = None, chunk: int = 200_000) -> np.ndarray:
    """Scaled Jacobian of each hexahedron: the minimum over its nodes of
    ``det(J) / (|J_u| |J_v| |J_w|)``, in [-1, 1] (1 for a cube).

    Parameters
    ----------
    points : (n, 3)
    cells : (m, (p+1)^3) node ids in tensor order (i fastest).
    order : int
        Mesh order p; for p = 1 this is the standard corner-based hex scaled Jacobian.
    ref_nodes : (p+1,) array, optional
        1-D reference node positions on [0, 1] (default equispaced).
    """
    p = int(order)
    if p == 1:
        return hex8_scaled_jacobian(points, cells)
    return jacobian_quality(points, cells, p, ref_nodes, chunk)[0]


def _node_jacobians(X: np.ndarray, D: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The columns ``J_u, J_v, J_w`` of the Jacobian at every node of the elements ``X``
    ``(m, (p+1)^3, 3)`` (tensor order, i fastest), each ``(m, p+1, p+1, p+1, 3)``."""
    X = X.reshape(-1, p + 1, p + 1, p + 1, 3)  # (m, k, j, i, 3)
    return np.einsum("ai,mkjid->mkjad", D, X), np.einsum("aj,mkjid->mkaid", D, X), np.einsum("ak,mkjid->majid", D, X)


def jacobian_ratio(points: np.ndarray, cells: np.ndarray, order: int = 1, ref_nodes: np.ndarray | None = None, chunk: int = 200_000) -> np.ndarray:
    """Jacobian ratio of each hexahedron: ``min det(J) / max |det(J)|`` over its nodes (the
    corners for p = 1), in [-1, 1]: 1 for a parallelepiped, <= 0 where it is inverted.

    The scaled Jacobian (:func:`scaled_jacobian`) normalises each node's determinant by its
    own edge lengths, so an element that tapers (one edge much shorter than the one
    opposite) but keeps right angles scores well; the ratio of the determinants across the
    element sees the taper (an edge 5 times shorter than its opposite: about 0.2). Quality
    measures built on Jacobian bounds over the whole element (gmsh's ``minSJ``) read such
    an element low.

    Parameters as :func:`scaled_jacobian`.
    """
    return jacobian_quality(points, cells, order, ref_nodes, chunk)[1]


def jacobian_quality(points: np.ndarray, cells: np.ndarray, order: int = 1, ref_nodes: np.ndarray | None = None, chunk: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """:func:`scaled_jacobian` and :func:`jacobian_ratio` of each hexahedron, the node
    Jacobians computed once for both (the same values as the two functions'). Parameters
    as :func:`scaled_jacobian`."""
    p = int(order)
    if p == 1:
        return _hex8_both(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(cells, dtype=np.int64).reshape(-1, 8))
    if ref_nodes is None:
        ref_nodes = np.linspace(0, 1, p + 1)
    D = lagrange_derivative_matrix(ref_nodes)
    sj, ratio = np.empty(len(cells)), np.empty(len(cells))
    for s in range(0, len(cells), chunk):
        Ju, Jv, Jw = _node_jacobians(points[cells[s : s + chunk]], D, p)
        det = np.einsum("...d,...d->...", Ju, np.cross(Jv, Jw))
        norm = np.linalg.norm(Ju, axis=-1) * np.linalg.norm(Jv, axis=-1) * np.linalg.norm(Jw, axis=-1)
        sj[s : s + chunk] = (det / np.maximum(norm, 1e-300)).reshape(len(det), -1).min(axis=1)
        det = det.reshape(len(det), -1)
        ratio[s : s + chunk] = det.min(axis=1) / np.maximum(np.abs(det).max(axis=1), 1e-300)
    return sj, ratio


def jacobian_ratio_summary(ratio: np.ndarray, layer: np.ndarray | None, below: float) -> dict:
    """min / mean / 1st percentile of the Jacobian ratios, how many are below ``below``, and
    (with the elements' block ``layer``: 0 core, 1 ring, 2 boundary layer) the same count
    and the minimum per layer: where the mesh tapers."""
    if len(ratio) == 0:
        return {"min": None, "mean": None, "p01": None, "below": below, "n_below": 0}
    out = {"min": float(ratio.min()), "mean": float(ratio.mean()), "p01": float(np.percentile(ratio, 1)),
           "below": below, "n_below": int((ratio < below).sum())}
    if layer is not None:
        layer = np.asarray(layer, np.int64)
        out["by_layer"] = {str(k): {"n": int((layer == k).sum()), "min": float(ratio[layer == k].min()), "n_below": int((ratio[layer == k] < below).sum())}
                           for k in np.unique(layer).tolist()}
    return out


def hex8_scaled_jacobian(points: np.ndarray, hexes: np.ndarray) -> np.ndarray:
    """Minimum corner scaled Jacobian ``(m,)`` of linear hexahedra in tensor corner order
    (corner ``i + 2 j + 4 k``), compiled and parallel over elements.

    At corner (i, j, k) the edge along +i is the hexahedron's i-edge at (j, k), and so on;
    the corner's value is ``det[e_i, e_j, e_k] / (|e_i| |e_j| |e_k|)``.
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    h = np.ascontiguousarray(hexes, dtype=np.int64).reshape(-1, 8)
    return _hex8_kernel(p, h)


@nb.njit(inline="always")
def _hex8_corner(points, hexes, e, c):
    """det of the edge vectors at corner ``c`` of hexahedron ``e`` and their lengths' product."""
    i, j, k = c & 1, (c >> 1) & 1, (c >> 2) & 1
    a0, a1 = hexes[e, 2 * j + 4 * k], hexes[e, 1 + 2 * j + 4 * k]
    b0, b1 = hexes[e, i + 4 * k], hexes[e, i + 2 + 4 * k]
    c0, c1 = hexes[e, i + 2 * j], hexes[e, i + 2 * j + 4]
    ux, uy, uz = points[a1, 0] - points[a0, 0], points[a1, 1] - points[a0, 1], points[a1, 2] - points[a0, 2]
    vx, vy, vz = points[b1, 0] - points[b0, 0], points[b1, 1] - points[b0, 1], points[b1, 2] - points[b0, 2]
    wx, wy, wz = points[c1, 0] - points[c0, 0], points[c1, 1] - points[c0, 1], points[c1, 2] - points[c0, 2]
    det = ux * (vy * wz - vz * wy) + uy * (vz * wx - vx * wz) + uz * (vx * wy - vy * wx)
    return det, np.sqrt((ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz) * (wx * wx + wy * wy + wz * wz))


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _hex8_kernel(points, hexes):
    m = hexes.shape[0]
    out = np.empty(m)
    for e in nb.prange(m):
        best = np.inf
        for c in range(8):
            det, ln = _hex8_corner(points, hexes, e, c)
            v = det / max(ln, 1e-300)
            if v < best:
                best = v
        out[e] = best
    return out


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _hex8_both(points, hexes):
    """:func:`_hex8_kernel` and the corners' ``min det / max |det|`` (:func:`jacobian_quality`)."""
    m = hexes.shape[0]
    sj, ratio = np.empty(m), np.empty(m)
    for e in nb.prange(m):
        best, lo, hi = np.inf, np.inf, 0.0
        for c in range(8):
            det, ln = _hex8_corner(points, hexes, e, c)
            best, lo, hi = min(best, det / max(ln, 1e-300)), min(lo, det), max(hi, abs(det))
        sj[e], ratio[e] = best, lo / max(hi, 1e-300)
    return sj, ratio


def quality_summary(sj: np.ndarray) -> dict:
    """min / mean / percentiles / count <= 0 of scaled Jacobians."""
    if len(sj) == 0:
        return {"min": None, "mean": None, "p01": None, "p05": None, "median": None, "n_invalid": 0, "n_elements": 0}
    return {
        "min": float(sj.min()),
        "mean": float(sj.mean()),
        "p01": float(np.percentile(sj, 1)),
        "p05": float(np.percentile(sj, 5)),
        "median": float(np.median(sj)),
        "n_invalid": int((sj <= 0).sum()),
        "n_elements": int(len(sj)),
    }
