"""Generated junctions for the junction tests: straight tubes (capsules) joined by a
smooth union, with their skeleton, signed distance and wall projection.

The union is blended (a polynomial smooth maximum, width ``blend`` × the thinner radius)
as segmented vessels are: the crotch is a smooth saddle, not a crease. The field is not an
exact distance off the wall, but its zero set is the wall and its gradient there is
nearly unit, which is all the block builder (ray casts) and the mesher (projection along
the gradient) need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from vmesh.skeleton import Skeleton


# The fields in compiled loops: the block builder and the mesher query them tens of thousands
# of times (rays, projections, their gradients) on a few hundred points at a time, where numpy's
# (points, capsules, 3) temporaries and per-capsule calls took 60-70 % of a junction test's
# time. Same arithmetic, in the same order, as the numpy expressions they replace (results
# differ from those in the last bit at most, as numpy's own do between batch sizes).
@numba.njit(cache=True, error_model="numpy")
def _capsule_fields(p, a, ab, abab, r):
    """``r[k]`` less the distance from ``p[i]`` to segment ``a[k] -> a[k] + ab[k]`` (``abab``
    its squared length): (points, capsules), positive inside."""
    n, m = p.shape[0], a.shape[0]
    f = np.empty((n, m))
    for i in range(n):
        for k in range(m):
            t = (p[i, 0] - a[k, 0]) * ab[k, 0] + (p[i, 1] - a[k, 1]) * ab[k, 1] + (p[i, 2] - a[k, 2]) * ab[k, 2]
            t = min(max(t / abab[k], 0.0), 1.0)
            e0 = p[i, 0] - (a[k, 0] + t * ab[k, 0])
            e1 = p[i, 1] - (a[k, 1] + t * ab[k, 1])
            e2 = p[i, 2] - (a[k, 2] + t * ab[k, 2])
            f[i, k] = r[k] - np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    return f


@numba.njit(cache=True, error_model="numpy")
def _smooth_union(f, order, widths):
    """Polynomial smooth maximum of the fields ``f`` (points, capsules), taken in ``order``
    with blend ``widths[j]`` for the ``j``-th."""
    out = np.empty(f.shape[0])
    for i in range(f.shape[0]):
        o = f[i, order[0]]
        for j in range(1, len(order)):
            fk, w = f[i, order[j]], widths[j]
            h = min(max(0.5 + 0.5 * (o - fk) / w, 0.0), 1.0)
            o = fk + (o - fk) * h + w * h * (1.0 - h)
        out[i] = o
    return out


def direction(azimuth_deg: float, elevation_deg: float = 0.0) -> np.ndarray:
    """Unit vector at ``azimuth`` in the xy-plane from +x, tilted ``elevation`` out of it."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])


@dataclass
class JunctionCase:
    """A generated vessel: capsules ``a[i] -> b[i]`` of radius ``r[i]`` and its skeleton."""

    name: str
    a: np.ndarray
    b: np.ndarray
    r: np.ndarray
    skeleton: Skeleton
    blend: float = 0.35

    def fields(self, p: np.ndarray) -> np.ndarray:
        """Each capsule's own field (p, k), positive inside."""
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        ab = b - a
        return _capsule_fields(np.ascontiguousarray(np.asarray(p, float).reshape(-1, 3)), np.ascontiguousarray(a), np.ascontiguousarray(ab),
                               np.sum(ab * ab, axis=1), np.asarray(self.r, float))

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Smooth-union field, positive inside."""
        p = np.asarray(p, float).reshape(-1, 3)
        f = self.fields(p)
        order = np.argsort(-self.r)  # thick vessels first: the blend scales with the thinner one
        return _smooth_union(np.ascontiguousarray(f), order, self.blend * np.asarray(self.r, float)[order])

    def gradient(self, p: np.ndarray, eps: float = 1e-5) -> np.ndarray:
        p = np.asarray(p, float).reshape(-1, 3)
        g = np.empty_like(p)
        for k in range(3):
            d = np.zeros(3)
            d[k] = eps
            g[:, k] = (self.distance(p + d) - self.distance(p - d)) / (2 * eps)
        return g

    def project(self, p: np.ndarray, iterations: int = 8) -> np.ndarray:
        """Points moved onto the wall along the field's gradient (Newton steps)."""
        x = np.asarray(p, float).reshape(-1, 3).copy()
        for _ in range(iterations):
            g = self.gradient(x)
            x -= (self.distance(x) / np.maximum(np.sum(g * g, axis=1), 1e-12))[:, None] * g
        return x


def _branch_adder(pts: list, edges: list, radii: list, a: list, b: list, r: list):
    """``add(start, join, d, rd, L)``: a branch of radius ``rd`` and length ``L`` from
    ``start`` (joined to node ``join``) along ``d``, appended to the skeleton lists and to
    the tube lists ``a``, ``b``, ``r`` (axis start, end past the tip, radius)."""

    def add(start, join, d, rd, L):
        p, e = _chain(start, d, L, 0.8 * rd, len(pts), join)
        pts.extend(p)
        edges.extend(e)
        radii.extend([rd] * len(p))
        a.append(start)
        b.append(start + (L + 2 * rd) * d)
        r.append(rd)

    return add


def _chain(start: np.ndarray, d: np.ndarray, length: float, spacing: float, first_id: int, join: int):
    """Skeleton nodes every ``spacing`` from ``start`` along ``d`` (excluding ``start``)."""
    n = max(2, int(round(length / spacing)))
    pts = start + np.outer(np.arange(1, n + 1) * (length / n), d)
    ids = first_id + np.arange(n)
    edges = np.c_[np.r_[join, ids[:-1]], ids]
    return pts, edges


def furcation(name: str, daughters, parent_radius: float = 1.0, parent_length: float = 8.0,
              length: float = 8.0, blend: float = 0.35) -> JunctionCase:
    """A parent along +x ending at the origin and daughters ``(direction, radius)`` from it.

    Branch lengths are in parent radii, at least 6 radii of the branch; the capsules run
    two radii past the skeleton's ends (open ends inside the tube)."""
    pts, edges, radii = [np.zeros(3)], [], [parent_radius]
    a, b, r = [], [], []
    branches = [(-np.array([1.0, 0, 0]), parent_radius, parent_length)]
    branches += [(np.asarray(d, float) / np.linalg.norm(d), rd, max(length, 6 * rd)) for d, rd in daughters]
    for d, rd, L in branches:
        p, e = _chain(np.zeros(3), d, L, 0.8 * rd, len(pts), 0)
        pts.extend(p)
        edges.extend(e)
        radii.extend([rd] * len(p))
        a.append(np.zeros(3))
        b.append((L + 2 * rd) * d)
        r.append(rd)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    return JunctionCase(name, np.asarray(a), np.asarray(b), np.asarray(r), sk, blend)


def fan(n: int, spread: float, r0: float = 2.0) -> JunctionCase:
    """A planar n-furcation (the generator's ``nfurcation``): a parent of radius ``r0`` into
    ``n`` daughters spread +-``spread`` degrees in a plane, radii by Murray's law (weights 1
    to 0.6)."""
    w = np.linspace(1.0, 0.6, n)
    radii = r0 * w / (w**3).sum() ** (1 / 3)
    angles = np.linspace(-spread, spread, n)
    return furcation(f"fan_{n}_{spread:g}", [(direction(a), r) for a, r in zip(angles, radii)], parent_radius=r0)


def fan_close_junction(n: int, spread: float, gap: float, side: tuple = (-110.0, 0.0), ratio: float = 0.3, r0: float = 2.0) -> JunctionCase:
    """:func:`fan` whose first daughter (at ``-spread``) is a junction ``gap`` parent radii
    from the fan: it goes on straight and gives off a branch (``ratio`` x ``r0``) at
    ``side`` = (azimuth, elevation) in degrees. The fan's neighbouring daughters part about
    3 parent radii out, so a junction nearer than that lies inside the fan's half-sections
    (s1 g0002 given: a 5-junction with a bifurcation 1.97 radii along a daughter 30 degrees
    from its neighbour; docs/junctions.md, h22/pair)."""
    w = np.linspace(1.0, 0.6, n)
    radii = r0 * w / (w**3).sum() ** (1 / 3)
    pts, edges, rad, a, b, r = [np.zeros(3)], [], [r0], [], [], []
    add = _branch_adder(pts, edges, rad, a, b, r)
    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), r0, 8.0)
    d0 = direction(-spread)
    add(np.zeros(3), 0, d0, radii[0], gap * r0)
    far = len(pts) - 1
    b[-1] = pts[far]  # its tube ends at the junction: the tubes past it are the junction's
    add(pts[far], far, d0, radii[0], 8 * r0)
    add(pts[far], far, direction(*side), ratio * r0, 6 * r0)
    for angle, rd in zip(np.linspace(-spread, spread, n)[1:], radii[1:]):
        add(np.zeros(3), 0, direction(angle), rd, max(8.0, 6 * rd))
    sk = Skeleton(np.asarray(pts), np.asarray(rad, float), np.asarray(edges))
    return JunctionCase(f"fan_close_{n}_{gap:g}_{side[0]:g}_{side[1]:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)


def junction_pair(gap: float, a1: float, a2: float, side: float) -> JunctionCase:
    """Two junctions in one plane: a trunk (radius 1) along +x, a side branch (0.6) at
    azimuth ``side`` at the origin, and ``gap`` on a junction into daughters (0.75, 0.7) at
    azimuths ``a1``, ``a2`` (``benchmarks/junction_pairs.py --pair``)."""
    J2 = np.array([gap, 0.0, 0.0])
    pts, edges, radii, a, b, r = [np.zeros(3), J2], [(0, 1)], [1.0, 0.9], [], [], []
    add = _branch_adder(pts, edges, radii, a, b, r)
    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), 1.0, 8.0)
    add(np.zeros(3), 0, direction(side), 0.6, 6.0)
    add(J2, 1, direction(a1), 0.75, 8.0)
    add(J2, 1, direction(a2), 0.7, 8.0)
    a.append(np.zeros(3)), b.append(J2), r.append(0.9)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    return JunctionCase(f"pair_{gap:g}_{a1:g}_{a2:g}_{side:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)


def close_junctions(gap: float, angle: float = 40.0, side: tuple = (90.0, 30.0)) -> JunctionCase:
    """A trunk along +x with a side branch at the origin and a bifurcation ``gap`` radii on.

    ``side`` is the side branch's (azimuth, elevation) in degrees: near the upper
    daughter's (``angle / 2``, -20) it leaves alongside that daughter, as a small branch
    that parts from the trunk just before a bifurcation does (sv_rpa's node 2)."""
    r0 = 1.0
    J2 = np.array([gap, 0, 0])
    pts = [np.zeros(3), J2]
    edges = [(0, 1)]
    radii = [r0, 0.9 * r0]
    a, b, r = [], [], []

    add = _branch_adder(pts, edges, radii, a, b, r)

    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), r0, 8.0)
    add(np.zeros(3), 0, direction(*side), 0.6 * r0, 6.0)
    add(J2, 1, direction(angle / 2, -20), 0.75 * r0, 8.0)
    add(J2, 1, direction(-angle / 2, -20), 0.7 * r0, 8.0)
    a.append(np.zeros(3))
    b.append(J2)
    r.append(0.9 * r0)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    return JunctionCase(f"close_junctions_{gap:g}_{side[0]:g}_{side[1]:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)


def bifurcation(angle: float, ratio: float, out_of_plane: float = 0.0, asymmetry: float = 0.5) -> JunctionCase:
    """Daughters ``angle`` degrees apart (split ``asymmetry`` : 1 - ``asymmetry`` about +x),
    radii 0.8 and 0.8 / ``ratio`` of the parent's, the second tilted ``out_of_plane``."""
    d1 = direction(asymmetry * angle)
    d2 = direction(-(1 - asymmetry) * angle, out_of_plane)
    return furcation(f"bif_{angle:g}_{ratio:g}_{out_of_plane:g}", [(d1, 0.8), (d2, 0.8 / ratio)])


def upstream_node(case: JunctionCase, shift: float) -> JunctionCase:
    """``case`` with its junction node moved ``shift`` parent radii back along the parent (+x
    is downstream), as centerline tools often join branches before the vessels part."""
    pts = case.skeleton.points.copy()
    pts[0] -= np.array([shift * case.r[0], 0.0, 0.0])
    sk = Skeleton(pts, case.skeleton.radii, case.skeleton.edges)
    return JunctionCase(f"{case.name}_up{shift:g}", case.a, case.b, case.r, sk, case.blend)


def trifurcation(spread: float, ratio: float = 1.0) -> JunctionCase:
    """Three daughters ``spread`` degrees off +x, 120 degrees apart around it."""
    s = np.radians(spread)
    ds = [np.array([np.cos(s), np.sin(s) * np.cos(t), np.sin(s) * np.sin(t)]) for t in np.radians([90, 210, 330])]
    return furcation(f"trif_{spread:g}_{ratio:g}", [(ds[0], 0.7), (ds[1], 0.7), (ds[2], 0.7 / ratio)])


def trifurcation_out_of_plane(side: float = 50.0, tilt: float = 33.0, ratio: float = 0.76) -> JunctionCase:
    """A trifurcation as the vessel generator grows one: two daughters ``side`` degrees
    either side of +x in the xy-plane (the thinner one at -``side``, radius 0.7 of the
    others'), the middle one along +x tilted ``tilt`` degrees out of that plane, radii
    ``ratio`` of the parent's (g0018's node 1: 50, 2 and -40 degrees, the middle 33
    degrees out of the plane)."""
    ds = [direction(side), direction(2.0, tilt), direction(-0.8 * side, 3.0)]
    return furcation(f"trif_out_{side:g}_{tilt:g}", [(ds[0], ratio), (ds[1], ratio), (ds[2], 0.7 * ratio)])


@dataclass
class CutCase(JunctionCase):
    """A :class:`JunctionCase` whose capsules are cut open by planes: ``cuts`` holds
    ``(capsule, point, outward normal)`` (flat open ends, each of one capsule)."""

    cuts: tuple = ()

    def fields(self, p: np.ndarray) -> np.ndarray:
        f = JunctionCase.fields(self, p)
        for k, c, n in self.cuts:
            f[:, k] = np.minimum(f[:, k], (np.asarray(c) - p) @ np.asarray(n))
        return f


def side_stub(angle: float = 70.0, ratio: float = 0.4, length: float = 1.5, half: float = 8.0, tilt: float = 0.0) -> tuple:
    """A straight vessel of radius 1 along x (cut open at +-``half``) with a side branch of
    radius ``ratio`` leaving the origin at ``angle`` degrees from +x, cut open ``length`` of
    its radii past the parent's wall, as the generator's ``stub`` feature makes it.

    The stub's skeleton is one segment from the junction to its cap, as ``thin_stubs``
    leaves it. Returns the case and its caps (inlet at -x, outlet_1 at +x, outlet_2 on the
    stub). ``tilt`` turns the stub's cut (and its cap's normal) that many degrees from the
    stub's axis towards +x: a slanted cut."""
    from vmesh.caps import Cap

    d = direction(angle)
    n_cut = np.cos(np.radians(tilt)) * d + np.sin(np.radians(tilt)) * np.array([1.0, 0.0, 0.0])
    n_cut /= np.linalg.norm(n_cut)
    L = 1.0 + length * ratio
    x = np.arange(-half, half + 1e-9, 0.8)
    pts = np.r_[np.c_[x, np.zeros((len(x), 2))], (L * d)[None]]
    j = int(np.argmin(np.abs(x)))
    pts[j] = 0.0
    n = len(x)
    edges = np.r_[np.c_[np.arange(n - 1), np.arange(1, n)], [[j, n]]]
    radii = np.r_[np.ones(n), ratio]
    sk = Skeleton(pts, radii, edges)
    ex = np.array([1.0, 0.0, 0.0])
    cuts = ((0, -half * ex, -ex), (0, half * ex, ex), (1, L * d, n_cut))
    case = CutCase(f"stub_{angle:g}_{ratio:g}_{length:g}" + (f"_{tilt:g}" if tilt else ""), np.array([-(half + 2) * ex, np.zeros(3)]),
                   np.array([(half + 2) * ex, (L + 2 * ratio) * d]), np.array([1.0, ratio]), sk, cuts=cuts)
    caps = [Cap(1, "inlet", -half * ex, -ex, 1.0), Cap(2, "outlet_1", half * ex, ex, 1.0), Cap(3, "outlet_2", L * d, n_cut, ratio)]
    return case, caps


def retrograde_branch(gap: float, back: float = 45.0, phi: float = 160.0, split: float = 40.0, ratio: float = 0.75) -> JunctionCase:
    """A bifurcation at the origin (parent from -x, radius 1; daughters ``split`` degrees
    either side of +x, radii 0.8 and 0.75) whose first daughter forks again ``gap`` parent
    radii on, where a branch (radius ``ratio`` × 0.8) leaves *backwards*: ``back`` degrees
    from the upstream direction, turned ``phi`` degrees about the daughter from the
    bifurcation plane's outer side (180: back into the crotch of the first bifurcation).

    As the generator's ``kissing`` feature grows one (g0016 given: 45 degrees from the
    parent's upstream direction, 2.2 radii from the junction before it, ``phi`` about
    160). The branch between the two junctions has nodes every 0.8 of its radius."""
    r0 = 1.0
    A, B = direction(-split), direction(split)
    J2 = gap * A
    n = np.array([0.0, 0.0, 1.0])
    side = np.cos(np.radians(phi)) * np.cross(A, n) + np.sin(np.radians(phi)) * n
    R = -np.cos(np.radians(back)) * A + np.sin(np.radians(back)) * side
    nmid = max(1, int(round(gap / 0.8)) - 1)
    pts = [np.zeros(3), J2] + [J2 * (k + 1) / (nmid + 1) for k in range(nmid)]
    radii = [r0, 0.8] + [0.8] * nmid
    way = [0] + list(range(2, 2 + nmid)) + [1]
    edges = list(zip(way[:-1], way[1:]))
    a, b, r = [], [], []

    add = _branch_adder(pts, edges, radii, a, b, r)

    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), r0, 8.0)
    add(np.zeros(3), 0, B, 0.75, 8.0)
    add(J2, 1, A, 0.8, 8.0)
    add(J2, 1, R, ratio * 0.8, 8.0)
    a.append(np.zeros(3))
    b.append(J2)
    r.append(0.8)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    return JunctionCase(f"retro_{gap:g}_{back:g}_{phi:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)


def side_sac(angle: float = 62.0, ratio: float = 1.4, length: float = 2.1, spacing: float = 0.75, half: float = 8.0) -> tuple:
    """A straight vessel of radius 1 along x (cut open at +-``half``) with a short, wide
    closed side branch: a sac of radius ``ratio`` leaving the origin at ``angle`` degrees
    from +x, its skeleton ending ``length`` parent radii from the junction, inside the
    sac's rounded end (a capsule whose axis ends half a sac radius short of the skeleton's
    end, so the dome reaches half a sac radius beyond it), with nodes every ``spacing``
    parent radii (one segment where ``length`` is under 1.5 ``spacing``).

    As the generator's ``aneurysm_side`` with ``radius_jump`` leaves one beside a junction
    (g0008 extracted, junction 17: a closed branch of 2.1 times the junction's radius with
    a radius of 1.4 times it, 62 degrees from the trunk). Returns the case and its caps
    (inlet at -x, outlet_1 at +x); the sac's end is closed (no cap)."""
    from vmesh.caps import Cap

    d = direction(angle)
    x = np.arange(-half, half + 1e-9, 0.8)
    j = int(np.argmin(np.abs(x)))
    x[j] = 0.0
    n = len(x)
    m = max(1, int(round(length / spacing)))
    sac = np.outer(np.arange(1, m + 1) * (length / m), d)
    pts = np.r_[np.c_[x, np.zeros((n, 2))], sac]
    edges = np.r_[np.c_[np.arange(n - 1), np.arange(1, n)], [[j, n]], np.c_[np.arange(n, n + m - 1), np.arange(n + 1, n + m)]]
    radii = np.r_[np.ones(n), np.full(m, ratio)]
    sk = Skeleton(pts, radii, edges)
    ex = np.array([1.0, 0.0, 0.0])
    cuts = ((0, -half * ex, -ex), (0, half * ex, ex))
    case = CutCase(f"sac_{angle:g}_{ratio:g}_{length:g}", np.array([-(half + 2) * ex, np.zeros(3)]),
                   np.array([(half + 2) * ex, (length - 0.5 * ratio) * d]), np.array([1.0, ratio]), sk, cuts=cuts)
    caps = [Cap(1, "inlet", -half * ex, -ex, 1.0), Cap(2, "outlet_1", half * ex, ex, 1.0)]
    return case, caps


def closed_end_past_branch(gap: float = 1.0, angle: float = 60.0, ratio: float = 0.6, half: float = 8.0, tip: float = 0.01) -> tuple:
    """A vessel of radius 1 along +x from an open inlet at ``-half`` that ends closed
    ``gap`` radii past the origin, where a side branch of radius ``ratio`` leaves at
    ``angle`` degrees from +x (cut open ``half`` along it). The parent's skeleton ends
    ``tip`` radii short of its dome's tip (a given centreline run to the wall), one
    segment past the junction.

    As seed 0 g0000 given's outlet node 76: 1.03 radii past the junction where the kissing
    vessel leaves, on the wall, so the closed branch is shorter than its junction's
    half-sections need. Returns the case and its caps (inlet at -x, outlet_1 on the branch)."""
    from vmesh.caps import Cap

    d = direction(angle)
    x = np.arange(-half, 1e-9, 0.8)
    x[-1] = 0.0
    n = len(x)
    side = np.outer(np.arange(1, int(half / 0.8) + 1) * 0.8, d)
    pts = np.r_[np.c_[x, np.zeros((n, 2))], [[gap, 0.0, 0.0]], side]
    m = len(side)
    edges = np.r_[np.c_[np.arange(n - 1), np.arange(1, n)], [[n - 1, n], [n - 1, n + 1]], np.c_[np.arange(n + 1, n + m), np.arange(n + 2, n + m + 1)]]
    radii = np.r_[np.ones(n + 1), np.full(m, ratio)]
    sk = Skeleton(pts, radii, edges)
    ex = np.array([1.0, 0.0, 0.0])
    end = side[-1]
    cuts = ((0, -half * ex, -ex), (1, end, d))
    case = CutCase(f"closed_past_{gap:g}_{angle:g}_{ratio:g}", np.array([-(half + 2) * ex, np.zeros(3)]),
                   np.array([(gap + tip - 1.0) * ex, end + 2 * ratio * d]), np.array([1.0, ratio]), sk, cuts=cuts)
    caps = [Cap(1, "inlet", -half * ex, -ex, 1.0), Cap(2, "outlet_1", end, d, ratio)]
    return case, caps


def bent_bulged_branch(turn: float = 75.0, leg: float = 1.2, at: float = 3.5, off: float = 1.0, bulge: float = 1.6,
                       ratio: float = 0.7, angle: float = 40.0) -> tuple:
    """A bifurcation at the origin (parent from -x, radius 1; daughters of radius ``ratio``
    ``angle`` degrees either side of +x) whose first daughter turns ``turn`` degrees
    ``leg`` from the junction and has a bulge past the bend: a ball of ``bulge`` times its
    radius, ``at`` of its radii along the second leg and ``off`` of them off its axis.

    As g0016 extracted's branch from junction 0 (radius 0.67: turns of 34 and 44 degrees
    within 1.4 of the junction, rays 3.6-4.1 radii long 2.5-4.7 along it). Returns the case
    and the arc length of the bulge's centre along the bent daughter."""
    A = direction(angle)
    A2 = direction(angle + turn)
    pts, edges, radii = [np.zeros(3)], [], [1.0]
    a, b, r = [], [], []
    add = _branch_adder(pts, edges, radii, a, b, r)
    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), 1.0, 8.0)
    add(np.zeros(3), 0, direction(-angle), ratio, 6.0)
    K = leg * A
    p, e = _chain(np.zeros(3), A, leg, 0.8 * ratio, len(pts), 0)  # the first leg ends at the bend, not past it
    pts.extend(p)
    edges.extend(e)
    radii.extend([ratio] * len(p))
    a.append(np.zeros(3))
    b.append(K)
    r.append(ratio)
    add(K, len(pts) - 1, A2, ratio, 6.0)
    c = K + at * ratio * A2 + off * ratio * np.cross(A2, [0.0, 0.0, 1.0])
    a.append(c)
    b.append(c + 1e-3 * A2)  # a ball: a capsule of (nearly) no length
    r.append(bulge * ratio)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    case = JunctionCase(f"bent_{turn:g}_{at:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)
    return case, leg + at * ratio


def blebbed_bifurcation(at: float = 3.5, bleb: float = 0.7, angle: float = 60.0, ratio: float = 0.8) -> JunctionCase:
    """``bifurcation``'s symmetric Y (daughters ``angle`` degrees apart, radius ``ratio``)
    with a bleb on the upper daughter's wall: a ball of radius ``bleb`` fused to its side
    ``at`` parent radii from the junction, without a skeleton branch of its own.

    Sections at the bleb have rays much longer than the daughter's radius, as hepatic_artery
    extracted's branch 11 -> 576 has where it curls back 3-4 radii from its 4-junction: a
    wall feature of the branch, past a stretch where its sections are clear of the
    junction. The lower daughter is the same branch without it."""
    d1, d2 = direction(angle / 2), direction(-angle / 2)
    case = furcation(f"bleb_{at:g}_{bleb:g}", [(d1, ratio), (d2, ratio)])
    side = np.cross(d1, [0.0, 0.0, 1.0])
    centre = at * d1 + (ratio + 0.5 * bleb) * side
    a = np.r_[case.a, [centre]]
    b = np.r_[case.b, [centre + 1e-6 * d1]]  # a ball: a capsule of (almost) no length
    return JunctionCase(case.name, a, b, np.r_[case.r, bleb], case.skeleton, case.blend)


def fused_acute_pair(angle: float = 15.0, short: float = 3.5, ratio: float = 0.8) -> JunctionCase:
    """A bifurcation at the origin (parent from -x, radius 1) whose daughters (radii
    ``ratio`` and 0.9 ``ratio``) leave ``angle`` degrees apart, the second ending after
    ``short`` in a junction of its own (a continuation 50 degrees further off and a side
    branch out of the plane) while the two tubes still overlap: they part only about
    (r1 + r2) / sin(angle) along. As g0006 given's junction 2 (15 degrees, junction 6
    inside the fused lumen)."""
    r1, r2 = ratio, 0.9 * ratio
    pts, edges, radii = [np.zeros(3)], [], [1.0]
    a, b, r = [], [], []
    add = _branch_adder(pts, edges, radii, a, b, r)
    add(np.zeros(3), 0, np.array([-1.0, 0, 0]), 1.0, 8.0)
    add(np.zeros(3), 0, direction(angle / 2), r1, 10.0)
    d2 = direction(-angle / 2)
    p, e = _chain(np.zeros(3), d2, short, 0.8 * r2, len(pts), 0)  # ends at its junction, not past it
    pts.extend(p)
    edges.extend(e)
    radii.extend([r2] * len(p))
    a.append(np.zeros(3))
    b.append(short * d2)
    r.append(r2)
    K, k = short * d2, len(pts) - 1
    add(K, k, direction(-angle / 2 - 50.0), 0.8 * r2, 6.0)
    add(K, k, direction(-angle / 2 - 90.0, 60.0), 0.6 * r2, 4.0)
    sk = Skeleton(np.asarray(pts), np.asarray(radii, float), np.asarray(edges))
    return JunctionCase(f"fused_acute_{angle:g}_{short:g}", np.asarray(a), np.asarray(b), np.asarray(r), sk)
