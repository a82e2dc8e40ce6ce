"""A narrow-band grid of signed distances: millions of queries per second.

The exact signed distance (:class:`~vmesh.geometry.sdf.SignedDistance`, an AABB tree)
answers a few hundred thousand closest-point queries per CPU-second, whatever the
surface's size. Meshing asks it many times at points near the wall (ray casts of wall
nodes, projections), so the distance is sampled once on a sparse grid around the wall and
interpolated trilinearly afterwards: a query becomes a handful of array gathers.

The grid is made of blocks of ``cells^3`` voxels; a dense table over the bounding box
maps block coordinates to the stored blocks, which are the blocks the surface passes
through and their neighbours (a shell about one block thick on each side of the wall).
Points outside the shell fall back to the exact distance. Projection onto the surface is
two Newton steps ``p - d grad d`` on the interpolated distance.
"""

from __future__ import annotations

import numpy as np


def surface_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """Points on every triangle, no further than ``spacing`` apart (barycentric lattices,
    vectorised over triangles that need the same subdivision)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    longest = np.maximum.reduce([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1)])
    k = np.maximum(1, np.ceil(longest / max(spacing, 1e-300)).astype(np.int64))
    out = [v]
    for n in np.unique(k):
        sel = np.flatnonzero(k == n)
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        u, w = (i[keep] / n)[None, :, None], (j[keep] / n)[None, :, None]
        out.append((a[sel, None] + u * (b - a)[sel, None] + w * (c - a)[sel, None]).reshape(-1, 3))
    return np.concatenate(out)


class GridSignedDistance:
    """Signed distance interpolated from a narrow-band grid around the wall.

    Parameters
    ----------
    exact : SignedDistance or TwoStepSignedDistance
        What the grid samples (and the fallback away from the wall).
    voxel_size : float, optional
        Edge of a voxel. Default: the median edge length of ``exact``'s triangles.
    cells : int
        Voxels along a block edge (the shell is about ``cells`` voxels thick on each side).
    max_nodes : int
        Upper bound on stored samples; the voxel size grows to stay below it.

    Attributes
    ----------
    Those of ``exact`` (``vertices``, ``faces``, ``n_faces``, ``bounds``, ``diagonal``,
    ``sign_method``), plus ``voxel_size``, ``n_blocks``, ``n_samples`` and ``build_s``.
    """

    def __init__(self, exact, voxel_size: float | None = None, cells: int = 4, max_nodes: int = 4_000_000):
        import time

        t0 = time.perf_counter()
        self.exact = exact
        self.name = getattr(exact, "name", "")
        self.vertices, self.faces = exact.vertices, exact.faces
        self.bounds, self.diagonal = exact.bounds, exact.diagonal
        self.sign_method = getattr(exact, "sign_method", "")
        v, f = np.asarray(exact.vertices), np.asarray(exact.faces)
        if voxel_size is None:
            e = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1)
            voxel_size = float(np.median(e))
        self.cells = int(cells)
        h = float(voxel_size)
        while True:
            L = self.cells * h
            self.origin = np.asarray(exact.bounds[0], float) - 1.5 * L
            samples = surface_samples(v, f, 0.5 * L)
            blocks = np.unique(np.floor((samples - self.origin) / L).astype(np.int64), axis=0)
            # neighbours too, so every point within one block of the wall is covered
            offs = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
            blocks = np.unique((blocks[:, None, :] + offs[None]).reshape(-1, 3), axis=0)
            if len(blocks) * (self.cells + 1) ** 3 <= max_nodes:
                break
            h *= 1.25
        self.voxel_size = h
        self.block_size = L
        bmin = blocks.min(axis=0)
        self._base = self.origin + bmin * L  # corner of block (0, 0, 0) of the table
        blocks = blocks - bmin
        self.table_shape = tuple(int(x) for x in blocks.max(axis=0) + 1)
        self.table = np.full(self.table_shape, -1, np.int64)
        self.table[blocks[:, 0], blocks[:, 1], blocks[:, 2]] = np.arange(len(blocks))
        self._block_origin = self._base + blocks * L
        n = self.cells + 1
        g = np.arange(n) * h
        local = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)  # (n^3, 3): [i, j, k]
        nodes = (self._block_origin[:, None, :] + local[None]).reshape(-1, 3)
        self.values = np.asarray(exact.distance(nodes), np.float64).reshape(len(blocks), n, n, n)
        self.n_blocks = len(blocks)
        self.n_samples = int(self.values.size)
        self.build_s = time.perf_counter() - t0

    @property
    def n_faces(self) -> int:
        return self.exact.n_faces

    def __repr__(self) -> str:
        return f"GridSignedDistance({self.n_blocks} blocks of {self.cells}^3 voxels of {self.voxel_size:.3g}, {self.n_samples} samples; {self.exact!r})"

    # -- interpolation -----------------------------------------------------------
    def _locate(self, p: np.ndarray):
        """Block id (-1 outside the shell), voxel indices and fractions of each point."""
        q = (p - self._base) / self.block_size
        b = np.floor(q).astype(np.int64)
        shape = np.array(self.table_shape)
        inside = np.all((b >= 0) & (b < shape), axis=1)
        bid = np.full(len(p), -1, np.int64)
        bi = b[inside]
        bid[inside] = self.table[bi[:, 0], bi[:, 1], bi[:, 2]]
        t = (q - b) * self.cells
        i = np.clip(np.floor(t).astype(np.int64), 0, self.cells - 1)
        return bid, i, t - i

    def _interpolate(self, p: np.ndarray, want_gradient: bool):
        bid, i, fr = self._locate(p)
        ok = bid >= 0
        b, i, fr = bid[ok], i[ok], fr[ok]
        V = self.values
        c = np.empty((len(b), 2, 2, 2))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    c[:, dx, dy, dz] = V[b, i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz]
        x, y, z = fr[:, 0:1], fr[:, 1:2], fr[:, 2:3]
        cx = c[:, 0] * (1 - x[:, :, None]) + c[:, 1] * x[:, :, None]  # (m, 2, 2) over y, z
        cxy = cx[:, 0] * (1 - y) + cx[:, 1] * y  # (m, 2) over z
        d = cxy[:, 0] * (1 - z[:, 0]) + cxy[:, 1] * z[:, 0]
        if not want_gradient:
            return ok, d, None
        h = self.voxel_size
        dxv = c[:, 1] - c[:, 0]  # (m, 2, 2)
        gx = (dxv[:, 0] * (1 - y) + dxv[:, 1] * y)
        gx = (gx[:, 0] * (1 - z[:, 0]) + gx[:, 1] * z[:, 0]) / h
        dyv = cx[:, 1] - cx[:, 0]  # (m, 2) over z
        gy = (dyv[:, 0] * (1 - z[:, 0]) + dyv[:, 1] * z[:, 0]) / h
        gz = (cxy[:, 1] - cxy[:, 0]) / h
        return ok, d, np.stack([gx, gy, gz], axis=1)

    # -- the SignedDistance interface -----------------------------------------------
    def distance(self, points) -> np.ndarray:
        """Signed distance ``(n,)``, positive inside (exact away from the wall's shell)."""
        p = np.asarray(points, float).reshape(-1, 3)
        ok, d, _ = self._interpolate(p, False)
        out = np.empty(len(p))
        out[ok] = d
        if not ok.all():
            out[~ok] = self.exact.distance(p[~ok])
        return out

    def gradient(self, points) -> np.ndarray:
        """Unit gradient ``(n, 3)`` of the signed distance, pointing into the vessel."""
        p = np.asarray(points, float).reshape(-1, 3)
        ok, _, g = self._interpolate(p, True)
        out = np.empty_like(p)
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        good = norm[:, 0] > 1e-12
        gg = np.where(good[:, None], g / np.maximum(norm, 1e-300), 0.0)
        out[ok] = gg
        redo = ~ok
        redo[np.flatnonzero(ok)[~good]] = True
        if redo.any():
            out[redo] = self.exact.gradient(p[redo])
        return out

    def project(self, points, steps: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points on the interpolated surface, signed distances and ``-1`` face ids (the
        grid knows no faces): ``steps`` Newton steps ``p - d grad d``; points outside the
        shell are projected exactly."""
        p = np.asarray(points, float).reshape(-1, 3)
        ok, d0, g = self._interpolate(p, True)
        closest = np.empty_like(p)
        dist = np.empty(len(p))
        face = np.full(len(p), -1, np.int64)
        x = p[ok].copy()
        d, gg = d0, g
        for _ in range(steps):
            n2 = np.maximum((gg * gg).sum(1), 1e-300)
            x = x - (d / n2)[:, None] * gg
            okk, d, gg = self._interpolate(x, True)
            if not okk.all():  # stepped out of the shell: finish exactly
                x[~okk] = self.exact.closest_points(x[~okk])
                full_d = np.zeros(len(x))
                full_g = np.zeros((len(x), 3))
                full_d[okk], full_g[okk] = d, gg
                d, gg = full_d, full_g
        # near the medial axis of a thin vessel the gradient is not unique and a Newton step
        # can land anywhere: keep only projections that moved by about |d| onto the zero set
        moved = np.linalg.norm(x - p[ok], axis=1)
        good = (np.abs(d) <= 0.05 * self.voxel_size) & (np.abs(moved - np.abs(d0)) <= 0.05 * np.abs(d0) + 0.25 * self.voxel_size)
        ok_idx = np.flatnonzero(ok)
        closest[ok_idx[good]], dist[ok_idx[good]] = x[good], d0[good]
        ok[ok_idx[~good]] = False
        if not ok.all():
            c, dd, fi = self.exact.project(p[~ok])
            closest[~ok], dist[~ok], face[~ok] = c, dd, fi
        return closest, dist, face

    def closest_points(self, points) -> np.ndarray:
        return self.project(points)[0]

    def inside(self, points) -> np.ndarray:
        return self.distance(points) > 0
