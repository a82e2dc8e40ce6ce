"""Cross-sections of a vessel: the O-grid template, section planes, frames and junction schemes.

Pure, vectorised kernels used by :mod:`vmesh.geometry.block_builder`.

The O-grid template
-------------------
One cross-section is an O-grid in its plane, written in a frame ``(e1, e2)`` with the
section normal ``n = e1 × e2``:

* a core lattice of ``a × b`` quads (``(a + 1)(b + 1)`` points),
* a ring of ``N = 2 (a + b)`` quads around the core,
* a boundary-layer ring of ``N`` quads whose outer corners lie on the wall.

A junction splits sections into two halves along the reference line (the template's
``x`` axis, along ``e1``), so the template needs a grid line through its centre along
``x``: ``b`` must be even. ``N = 6 → 1 × 2``, ``N = 8 → 2 × 2`` (the default),
``N = 10 → 3 × 2``, ``N = 12 → 4 × 2`` ... ``N = 4`` (a ``1 × 1`` core) has no such line
and only serves skeletons without junctions.

Template coordinates are normalised: the core lattice spans ``[-w, w] × [-h, h]`` with
``w h = 1`` and square cells; ring and outer vertices sit on rays at the polar angles
of the core boundary points. A section is placed in space by casting rays in its plane
from its centre to the wall (:func:`cast_rays`) and scaling the template by the ray
lengths (:func:`section_vertices`).

Junctions
---------
At a junction with neighbour directions ``d_i`` the reference line ``u``
(:func:`junction_axis`) is ``d1×d2 + d2×d3 + d3×d1`` for three neighbours and the normal
of a best-fitting plane otherwise; neighbours are ordered by angle around ``u`` and
the space around the junction is split by half-planes through the line ``(c, u)``
between consecutive neighbours (:func:`separator_angles`). Each half-plane carries a
half O-grid (the template's ``y ≥ 0`` part).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..blocks import (
    AXIS_AROUND,
    AXIS_CORE,
    AXIS_LAYER,
    AXIS_RING,
    LAYER_BOUNDARY,
    LAYER_CORE,
    LAYER_RING,
)

from . import rays as _rays

# their old home: the builder and the skeleton reach them as ``cs.cast_rays``, ``cs.RayCache``
cast_rays, RayCache = _rays.cast_rays, _rays.RayCache

VERTEX_CORE, VERTEX_RING, VERTEX_OUTER = 0, 1, 2
_TWO_PI = 2.0 * np.pi


# ---------------------------------------------------------------------------
# small vector helpers
# ---------------------------------------------------------------------------
def unit(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """``v`` normalised along ``axis`` (zero vectors stay zero)."""
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.where(n > 1e-300, n, 1.0)


def any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each row of ``n`` (deterministic)."""
    n = unit(np.atleast_2d(n))
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    return unit(axis - np.sum(axis * n, axis=1, keepdims=True) * n)


def reject(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Component of ``v`` perpendicular to the unit vectors ``n`` (row-wise)."""
    return v - np.sum(v * n, axis=-1, keepdims=True) * n


def rotate_about(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues rotation of vectors ``v`` about unit ``axis`` by ``angle`` (row-wise)."""
    v = np.asarray(v, float)
    k = np.asarray(axis, float)
    c = np.cos(angle)[..., None]
    s = np.sin(angle)[..., None]
    return v * c + np.cross(k, v) * s + k * np.sum(k * v, axis=-1, keepdims=True) * (1 - c)


def signed_angle(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle (radians, in (-π, π]) rotating ``a`` onto ``b`` about ``axis`` (row-wise)."""
    return np.arctan2(np.sum(np.cross(a, b) * axis, axis=-1), np.sum(a * b, axis=-1))


# ---------------------------------------------------------------------------
# the O-grid template
# ---------------------------------------------------------------------------
def core_shape(blocks_around: int) -> tuple[int, int]:
    """Core lattice ``(a, b)`` with ``2 (a + b) = blocks_around``, ``b`` even when possible.

    The most square core with an even ``b`` (a grid line through the centre along ``x``);
    ``blocks_around = 4`` gives the ``1 × 1`` core, which cannot be split.
    """
    n = int(blocks_around)
    if n < 4 or n % 2:
        raise ValueError(f"blocks_around must be an even number >= 4, got {blocks_around}")
    half = n // 2
    if half == 2:
        return 1, 1
    best = None
    for b in range(2, half, 2):
        a = half - b
        key = (abs(a - b), -a)
        if best is None or key < best[0]:
            best = (key, (a, b))
    return best[1]


@dataclass(frozen=True)
class OGridTemplate:
    """The 2-D O-grid of one cross-section (see the module docstring).

    Attributes
    ----------
    n_around : int
        Blocks around the circumference, ``N = 2 (a + b)``.
    a, b : int
        Core quads along ``x`` (the reference direction) and ``y``.
    xy : (nv, 2) float
        Template coordinates: core lattice points, then ``N`` ring and ``N`` outer
        vertices (unit directions).
    kind : (nv,) int
        ``VERTEX_CORE``, ``VERTEX_RING`` or ``VERTEX_OUTER``.
    loop : (N,) int
        Core boundary vertices, counter-clockwise from ``(w, 0)``.
    loop_angle : (N,) float
        Polar angles of the loop vertices: the directions of ring and outer vertex ``k``.
    quads : (nq, 4) int
        Counter-clockwise quads: core, ring, boundary layer.
    quad_layer : (nq,) int
        ``LAYER_*`` of each quad.
    quad_axes : (nq, 2) int
        ``AXIS_*`` kind of the quad's first (corner 0→1) and second (0→3) edge.
    quad_wall : (nq,) bool
        The quad's edge 1-2 lies on the wall (boundary-layer quads).
    ray_angles : (nr,) float
        Directions in which rays are cast: loop angles and the four axis directions.
    mirror : (nv,) int
        Vertex at ``(x, -y)``.
    symmetries : tuple of (angle, (nv,) int)
        Rotations mapping the template onto itself: ``perm[v]`` is the vertex at the
        position of ``v`` rotated by ``angle``.
    splittable : bool
        The template has a grid line through its centre along ``x`` (``b`` even).
    """

    n_around: int
    a: int
    b: int
    xy: np.ndarray
    kind: np.ndarray
    loop: np.ndarray
    loop_angle: np.ndarray
    quads: np.ndarray
    quad_layer: np.ndarray
    quad_axes: np.ndarray
    quad_wall: np.ndarray
    ray_angles: np.ndarray
    mirror: np.ndarray
    symmetries: tuple = field(default_factory=tuple)
    splittable: bool = True

    # duplicates: count properties like Skeleton's, SurfaceMesh's and HexMesh's: each class counts its own arrays
    @property
    def n_vertices(self) -> int:
        return len(self.xy)

    @property
    def n_quads(self) -> int:
        return len(self.quads)

    @property
    def ring(self) -> np.ndarray:
        return np.flatnonzero(self.kind == VERTEX_RING)

    @property
    def outer(self) -> np.ndarray:
        return np.flatnonzero(self.kind == VERTEX_OUTER)

    @property
    def upper(self) -> np.ndarray:
        """Boolean mask of the vertices of the upper half (``y >= 0``)."""
        return self.xy[:, 1] >= -1e-12

    @property
    def spine(self) -> np.ndarray:
        """Boolean mask of the vertices on the split line ``y = 0``."""
        return np.abs(self.xy[:, 1]) <= 1e-12

    @property
    def symmetry_angle(self) -> float:
        """Smallest rotation (radians) mapping the template onto itself."""
        return float(min(a for a, _ in self.symmetries if a > 0))


def _match_vertices(xy: np.ndarray, kind: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Index of the vertex of the same kind at each ``target`` position (-1 when none)."""
    d = np.linalg.norm(xy[None, :, :] - target[:, None, :], axis=2)
    d[kind[None, :] != kind[:, None]] = np.inf
    j = np.argmin(d, axis=1)
    return np.where(d[np.arange(len(xy)), j] < 1e-9, j, -1)


def o_grid_template(blocks_around: int = 8) -> OGridTemplate:
    """Build the O-grid template with ``blocks_around`` ring (and boundary-layer) blocks."""
    a, b = core_shape(blocks_around)
    n = 2 * (a + b)
    w, h = np.sqrt(a / b), np.sqrt(b / a)
    xs = np.linspace(-w, w, a + 1)
    ys = np.linspace(-h, h, b + 1)
    gx, gy = np.meshgrid(xs, ys)  # row j (y), column i (x)
    core = np.c_[gx.ravel(), gy.ravel()]
    lat = lambda i, j: j * (a + 1) + i  # noqa: E731
    # counter-clockwise boundary walk of the lattice, then rotated to start at (w, 0) or nearest
    walk = [lat(i, 0) for i in range(a)] + [lat(a, j) for j in range(b)]
    walk += [lat(i, b) for i in range(a, 0, -1)] + [lat(0, j) for j in range(b, 0, -1)]
    walk = np.asarray(walk)
    ang = np.mod(np.arctan2(core[walk, 1], core[walk, 0]), _TWO_PI)
    start = int(np.argmin(np.where(ang < 1e-12, 0.0, ang)))
    loop = np.roll(walk, -start)
    loop_angle = np.mod(np.arctan2(core[loop, 1], core[loop, 0]), _TWO_PI)
    nc = len(core)
    dirs = np.c_[np.cos(loop_angle), np.sin(loop_angle)]
    xy = np.vstack([core, dirs, dirs])
    kind = np.r_[np.full(nc, VERTEX_CORE), np.full(n, VERTEX_RING), np.full(n, VERTEX_OUTER)]
    ring = nc + np.arange(n)
    outer = nc + n + np.arange(n)
    k1 = np.roll(np.arange(n), -1)
    quads, layer, axes = [], [], []
    for j in range(b):
        for i in range(a):
            quads.append([lat(i, j), lat(i + 1, j), lat(i + 1, j + 1), lat(i, j + 1)])
            layer.append(LAYER_CORE)
            axes.append([AXIS_CORE, AXIS_CORE])
    for k in range(n):
        quads.append([loop[k], ring[k], ring[k1[k]], loop[k1[k]]])
        layer.append(LAYER_RING)
        axes.append([AXIS_RING, AXIS_AROUND])
    for k in range(n):
        quads.append([ring[k], outer[k], outer[k1[k]], ring[k1[k]]])
        layer.append(LAYER_BOUNDARY)
        axes.append([AXIS_LAYER, AXIS_AROUND])
    quads = np.asarray(quads, np.int64)
    layer = np.asarray(layer, np.int64)
    # mirror and rotations by matching positions (outer vertices are told apart by kind)
    mirror = _match_vertices(xy, kind, xy * [1.0, -1.0])
    syms = []
    for k in range(4):
        t = k * np.pi / 2
        c, s = np.cos(t), np.sin(t)
        perm = _match_vertices(xy, kind, xy @ np.array([[c, s], [-s, c]]))
        if np.all(perm >= 0):
            syms.append((t, perm))
    axis_angles = np.array([0.0, 0.5, 1.0, 1.5]) * np.pi
    rays = np.unique(np.round(np.r_[loop_angle, axis_angles], 12))
    return OGridTemplate(
        n_around=n,
        a=a,
        b=b,
        xy=xy,
        kind=kind,
        loop=loop,
        loop_angle=loop_angle,
        quads=quads,
        quad_layer=layer,
        quad_axes=np.asarray(axes, np.int64),
        quad_wall=layer == LAYER_BOUNDARY,
        ray_angles=rays,
        mirror=mirror,
        symmetries=tuple(syms),
        splittable=(b % 2 == 0) and np.any(np.abs(ys) < 1e-12),
    )


def ray_index(template: OGridTemplate, angles: np.ndarray) -> np.ndarray:
    """Index into ``template.ray_angles`` of each angle (which must be one of them)."""
    ang = np.mod(np.asarray(angles, float), _TWO_PI)
    d = np.abs(np.angle(np.exp(1j * (template.ray_angles[None, :] - ang.reshape(-1)[:, None]))))
    return np.argmin(d, axis=1).reshape(np.shape(angles))


#: least distance of a core quadrant's corner beyond the chord between its axis points
#: (:func:`section_vertices`), as a multiple of the chord's distance along the diagonal
CORE_CONVEX = 1.2


def section_vertices(
    template: OGridTemplate,
    centers: np.ndarray,
    e1: np.ndarray,
    e2: np.ndarray,
    ray_length: np.ndarray,
    core_size: np.ndarray | float,
    layer_thickness: np.ndarray | float,
) -> np.ndarray:
    """Place the template in space from ray lengths.

    Parameters
    ----------
    template : OGridTemplate
    centers, e1, e2 : (m, 3)
        Section centres and in-plane frames.
    ray_length : (m, nr)
        Distance from the centre to the wall along each of ``template.ray_angles``.
    core_size : float or (m,)
        Core half-width relative to the ray lengths (0.35: the core corner at
        0.35·√2 of the way to the wall for a square core).
    layer_thickness : float or (m,)
        Boundary-layer ring thickness relative to the ray length.

    Returns
    -------
    (m, nv, 3) vertex positions: outer vertices on the wall, ring vertices at
    ``1 - layer_thickness`` of their ray, core points mapped quadrant by quadrant
    bilinearly from the axis and diagonal rays (so the core follows oval or lopsided
    sections).
    """
    t = template
    c = np.asarray(centers, float)
    m = len(c)
    R = np.asarray(ray_length, float).reshape(m, -1)
    kappa = np.broadcast_to(np.asarray(core_size, float), (m,))[:, None]
    lam = np.broadcast_to(np.asarray(layer_thickness, float), (m,))[:, None]
    out = np.empty((m, t.n_vertices, 3))
    # ring and outer vertices along their rays
    k = ray_index(t, t.loop_angle)
    dirs = np.cos(t.loop_angle)[None, :, None] * e1[:, None, :] + np.sin(t.loop_angle)[None, :, None] * e2[:, None, :]
    ring, outer = t.ring, t.outer
    out[:, outer] = c[:, None, :] + R[:, k, None] * dirs
    out[:, ring] = c[:, None, :] + ((1.0 - lam) * R[:, k])[:, :, None] * dirs
    # core: bilinear per quadrant between the centre, the two axis rays and the diagonal ray
    core = np.flatnonzero(t.kind == VERTEX_CORE)
    x, y = t.xy[core, 0], t.xy[core, 1]
    w, h = np.abs(t.xy[core, 0]).max(), np.abs(t.xy[core, 1]).max()
    sx, sy = np.where(x >= 0, 1.0, -1.0), np.where(y >= 0, 1.0, -1.0)
    ax_x = ray_index(t, np.where(sx > 0, 0.0, np.pi))
    ax_y = ray_index(t, np.where(sy > 0, 0.5 * np.pi, 1.5 * np.pi))
    diag_angle = np.arctan2(sy * h, sx * w)
    ax_d = ray_index(t, diag_angle)
    px = (kappa * w * R[:, ax_x] * sx)[:, :, None] * e1[:, None, :]
    py = (kappa * h * R[:, ax_y] * sy)[:, :, None] * e2[:, None, :]
    dd = np.cos(diag_angle)[None, :, None] * e1[:, None, :] + np.sin(diag_angle)[None, :, None] * e2[:, None, :]
    # a short diagonal ray (a notch in a lumpy section) would put the quadrant's corner
    # inside the chord between its axis points: a dart whose core block inverts, however
    # small the core. The corner stays CORE_CONVEX times beyond that chord (every ellipse of
    # aspect up to 10 is beyond it at 1.21 and more: only notched sections move)
    rx, ry = R[:, ax_x], R[:, ax_y]
    rd = np.maximum(R[:, ax_d], CORE_CONVEX * rx * ry / np.maximum(rx + ry, 1e-300))
    pd = (kappa * np.hypot(w, h) * rd)[:, :, None] * dd
    s = (np.abs(x) / w)[None, :, None]
    q = (np.abs(y) / h)[None, :, None]
    out[:, core] = c[:, None, :] + s * (1 - q) * px + (1 - s) * q * py + s * q * pd
    return out


def ray_directions(e1: np.ndarray, e2: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(m, k, 3) unit directions ``cos θ e1 + sin θ e2`` for every frame and angle."""
    ang = np.asarray(angles, float)
    return np.cos(ang)[None, :, None] * e1[:, None, :] + np.sin(ang)[None, :, None] * e2[:, None, :]


# ---------------------------------------------------------------------------
# planes and frames
# ---------------------------------------------------------------------------
def bisector_normals(prev: np.ndarray, points: np.ndarray, nxt: np.ndarray, radii: np.ndarray, bias: float = 1.0) -> np.ndarray:
    """Normals of the bisecting planes at nodes with two neighbours.

    ``n = unit(w_in d_in + w_out d_out)`` with ``d_in = unit(p - prev)``,
    ``d_out = unit(next - p)`` and weights ``w = (radius / segment length) ** bias``: with
    ``bias > 0`` the plane turns towards perpendicular to the shorter segment, which
    keeps the tilted section from reaching across it.
    """
    din = points - prev
    dout = nxt - points
    lin = np.linalg.norm(din, axis=1)
    lout = np.linalg.norm(dout, axis=1)
    r = np.asarray(radii, float)
    win = (r / np.maximum(lin, 1e-12)) ** bias
    wout = (r / np.maximum(lout, 1e-12)) ** bias
    return unit(win[:, None] * unit(din) + wout[:, None] * unit(dout))


def transport_frames(positions: np.ndarray, tangents: np.ndarray, first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Rotation-minimising frames by the double reflection method (Wang et al. 2008).

    Parameters
    ----------
    positions, tangents : (B, K, 3)
        Padded polylines (``counts[i]`` valid points each) and their unit tangents.
    first : (B, 3)
        Reference direction at the first point (perpendicular to its tangent).
    counts : (B,)
        Number of valid points per polyline.

    Returns
    -------
    (B, K, 3) reference directions, each perpendicular to its tangent; entries past
    ``counts`` repeat the last valid one.
    """
    x = np.asarray(positions, float)
    t = np.asarray(tangents, float)
    B, K, _ = x.shape
    r = np.empty_like(x)
    r[:, 0] = unit(reject(np.asarray(first, float), t[:, 0]))
    for i in range(K - 1):
        valid = (i + 1) < counts
        v1 = x[:, i + 1] - x[:, i]
        c1 = np.sum(v1 * v1, axis=1, keepdims=True)
        c1s = np.where(c1 > 1e-24, c1, 1.0)
        rL = r[:, i] - np.where(c1 > 1e-24, 2.0 / c1s * np.sum(v1 * r[:, i], 1, keepdims=True) * v1, 0.0)
        tL = t[:, i] - np.where(c1 > 1e-24, 2.0 / c1s * np.sum(v1 * t[:, i], 1, keepdims=True) * v1, 0.0)
        v2 = t[:, i + 1] - tL
        c2 = np.sum(v2 * v2, axis=1, keepdims=True)
        c2s = np.where(c2 > 1e-24, c2, 1.0)
        rn = rL - np.where(c2 > 1e-24, 2.0 / c2s * np.sum(v2 * rL, 1, keepdims=True) * v2, 0.0)
        rn = unit(reject(rn, t[:, i + 1]))
        r[:, i + 1] = np.where(valid[:, None], rn, r[:, i])
    return r


def residual_twist(transported: np.ndarray, target: np.ndarray, normal: np.ndarray, symmetry: float) -> tuple[np.ndarray, np.ndarray]:
    """Smallest rotation about ``normal`` taking ``transported`` to a symmetric image of ``target``.

    Returns
    -------
    angle : (n,) float
        Signed twist in ``(-symmetry/2, symmetry/2]``.
    turns : (n,) int
        How many ``symmetry`` steps the target's frame is ahead of the twisted frame:
        the twisted frame equals ``target`` rotated by ``-turns × symmetry``.
    """
    phi = signed_angle(transported, reject(target, normal), normal)
    turns = np.round(phi / symmetry).astype(np.int64)
    return phi - turns * symmetry, turns


# ---------------------------------------------------------------------------
# junctions
# ---------------------------------------------------------------------------
def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors on the upper hemisphere (z >= 0)."""
    i = np.arange(n) + 0.5
    z = i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def order_around(u: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles of ``directions`` around ``u`` and the basis measuring them.

    Returns
    -------
    angle : (m,) angles in [0, 2π) in the basis ``(p, q)`` of the plane ⟂ u (``p × q = u``).
    p, q : (3,) the basis; ``p`` points along the first direction's projection.
    """
    u = unit(np.asarray(u, float))
    d = unit(np.asarray(directions, float))
    proj = reject(d, u[None, :])
    k = int(np.argmax(np.linalg.norm(proj, axis=1)))
    p = unit(proj[k])
    q = np.cross(u, p)
    return np.mod(np.arctan2(proj @ q, proj @ p), _TWO_PI), p, q


def gap_statistics(u: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest angular gap between consecutive projected directions and largest elevation,
    for many candidate axes at once.

    Parameters
    ----------
    u : (c, 3) unit candidate axes
    directions : (m, 3) unit directions

    Returns
    -------
    min_gap : (c,) radians
    max_elevation : (c,) radians (angle between a direction and the plane ⟂ u)
    """
    u = np.atleast_2d(u)
    d = np.asarray(directions, float)
    sin_el = d @ u.T  # (m, c)
    elev = np.arcsin(np.clip(np.abs(sin_el), 0, 1)).max(axis=0)
    p = any_perpendicular(u)
    q = np.cross(u, p)
    ang = np.mod(np.arctan2(d @ q.T, d @ p.T), _TWO_PI)  # (m, c)
    s = np.sort(ang, axis=0)
    gaps = np.diff(np.vstack([s, s[:1] + _TWO_PI]), axis=0)
    return gaps.min(axis=0), elev


def junction_axis(directions: np.ndarray, max_elevation: float = np.pi / 3, elevation_weight: float = 0.5) -> tuple[np.ndarray, float, float]:
    """Reference line ``u`` of a junction from the unit directions to its neighbours.

    Three neighbours: ``u = d1×d2 + d2×d3 + d3×d1`` (the normal of the plane through
    the tips of the directions). More: the axis maximising the smallest angular gap
    between the neighbours ordered around it, penalised by their elevation out of the
    plane ⟂ u (``score = min gap − elevation_weight × rms elevation``), searched over
    the best-fit plane normal, normals of pairs of directions and a sphere of
    candidates; axes leaving some direction more than ``max_elevation`` out of the plane
    are only taken when no other exists. The sign follows the cyclic sum of
    ``d_i × d_{i+1}`` in the given order, as the three-neighbour formula does.

    Returns
    -------
    u : (3,) unit axis
    min_gap : float, radians
    max_elevation : float, radians
    """
    d = unit(np.asarray(directions, float))
    m = len(d)
    cyc = np.cross(d, np.roll(d, -1, axis=0)).sum(axis=0)
    if m == 3 and np.linalg.norm(cyc) > 1e-6:
        u = unit(cyc)
    else:
        cands = [fibonacci_sphere(600)]
        _, _, vt = np.linalg.svd(d - 0 * d.mean(axis=0))
        cands.append(vt[-1:])
        i, j = np.triu_indices(m, 1)
        pair = np.cross(d[i], d[j])
        cands.append(pair[np.linalg.norm(pair, axis=1) > 1e-6])
        if np.linalg.norm(cyc) > 1e-6:
            cands.append(cyc[None, :])
        c = unit(np.vstack(cands))
        gap, elev = gap_statistics(c, d)
        rms = np.sqrt(np.mean((d @ c.T) ** 2, axis=0))
        score = gap - elevation_weight * np.arcsin(np.clip(rms, 0, 1)) - 10.0 * (elev > max_elevation)
        u = c[int(np.argmax(score))]
        if np.linalg.norm(cyc) > 1e-6 and u @ cyc < 0:
            u = -u
    gap, elev = gap_statistics(u[None, :], d)
    return u, float(gap[0]), float(elev[0])


def separator_angles(branch_angle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bisecting separator angles between neighbours ordered around the junction axis.

    Parameters
    ----------
    branch_angle : (m,) angles of the neighbours around ``u``

    Returns
    -------
    order : (m,) neighbours sorted by angle
    separator : (m,) angle of the half-plane between ``order[h]`` and ``order[h + 1]``
    gap : (m,) angular gap between them
    """
    order = np.argsort(branch_angle, kind="stable")
    a = branch_angle[order]
    gap = np.mod(np.roll(a, -1) - a, _TWO_PI)
    gap = np.where(gap <= 0, _TWO_PI, gap)
    return order, np.mod(a + 0.5 * gap, _TWO_PI), gap
