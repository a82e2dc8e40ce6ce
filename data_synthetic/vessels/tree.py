"""Random vessel trees: growth with Murray's-law radii and angles, and the hard features.

A tree is a list of :class:`Branch` (a finely sampled axis with radii) plus aneurysm sacs
(spheres). Branches start on a point of their parent branch (junctions); a loop branch also
ends on a point of another branch. Lengths are in mm; :mod:`.surface` turns a tree into a
triangle surface and :func:`skeleton_of` into its true skeleton.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

#: Fine axis step, in local radii.
AXIS_STEP = 0.35
#: Skeleton node spacing, in local radii.
NODE_SPACING = 1.1
#: Clearance factor between non-adjacent vessels of a clean tree: gap > CLEAR * (r_a + r_b).
CLEAR = 1.35


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perpendicular(t, rng=None):
    """A unit vector normal to ``t`` (random when ``rng`` is given)."""
    a = rng.standard_normal(3) if rng is not None else (np.array([1.0, 0, 0]) if abs(t[0]) < 0.9 else np.array([0, 1.0, 0]))
    a = a - (a @ t) * t
    return unit(a)


def rotate_towards(t, m, angle):
    """Direction at ``angle`` (radians) from unit ``t`` towards unit ``m`` (``m`` normal to ``t``)."""
    return unit(np.cos(angle) * t + np.sin(angle) * m)


@dataclass
class Branch:
    """One vessel axis.

    Attributes
    ----------
    pts, rad : ndarray
        Fine axis points (n, 3) and radii (n,).
    parent, parent_at : int
        Branch and point index where ``pts[0]`` lies (-1: a root).
    end_on : tuple of (int, int) or None
        A loop branch's last point lies on this (branch, point index).
    kind : str
        ``vessel``, ``stub``, ``side`` (large radius ratio), ``loop``, ``kissing`` or
        ``aneurysm`` (the skeleton of a sac; no tube).
    tags : dict of int -> list of str
        Skeleton tags of points that must be nodes (features).
    """

    pts: np.ndarray
    rad: np.ndarray
    parent: int = -1
    parent_at: int = 0
    end_on: tuple | None = None
    kind: str = "vessel"
    tags: dict = field(default_factory=dict)

    @property
    def tube(self) -> bool:
        return self.kind != "aneurysm"

    @property
    def s(self) -> np.ndarray:
        return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(self.pts, axis=0), axis=1))]

    def tangent(self, i: int) -> np.ndarray:
        i = min(max(i, 1), len(self.pts) - 1)
        return unit(self.pts[i] - self.pts[i - 1])


@dataclass
class Tree:
    """Branches, aneurysm sacs (centre, radius) and the features placed (name -> count)."""

    branches: list = field(default_factory=list)
    sacs: list = field(default_factory=list)
    features: Counter = field(default_factory=Counter)

    def children(self, b: int) -> list[int]:
        return [k for k, br in enumerate(self.branches) if br.parent == b]

    def end_children(self, b: int) -> list[int]:
        n = len(self.branches[b].pts) - 1
        return [k for k in self.children(b) if self.branches[k].parent_at == n]

    def points(self, skip=()):
        """All tube axis points, radii and branch ids, without the branches in ``skip``."""
        use = [k for k, b in enumerate(self.branches) if b.tube and k not in skip]
        if not use:
            return np.zeros((0, 3)), np.zeros(0), np.zeros(0, int)
        return (np.concatenate([self.branches[k].pts for k in use]), np.concatenate([self.branches[k].rad for k in use]),
                np.concatenate([np.full(len(self.branches[k].pts), k) for k in use]))

    def clear_of(self, pts, rad, keep_out: list, skip=()) -> bool:
        """Whether a tube (``pts``, ``rad``) keeps CLEAR * (r_a + r_b) from every other tube;
        ``keep_out`` lists (centre, radius) balls (junctions) where contact is expected."""
        P, R, _ = self.points(skip)
        if len(P) == 0:
            return True
        far = np.ones(len(pts), bool)
        far_P = np.ones(len(P), bool)
        for c, r in keep_out:
            far &= np.linalg.norm(pts - c, axis=1) > r
            far_P &= np.linalg.norm(P - c, axis=1) > r
        if not far.any() or not far_P.any():
            return True
        P, R = P[far_P], R[far_P]
        reach = CLEAR * (rad[far] + R.max())
        d, j = cKDTree(P).query(pts[far], k=min(16, len(P)), distance_upper_bound=float(reach.max()))
        d, j = np.atleast_2d(d), np.atleast_2d(j)
        hit = np.isfinite(d)
        need = CLEAR * (rad[far][:, None] + R[np.minimum(j, len(R) - 1)])
        return not np.any(hit & (d < need))


# ---------------------------------------------------------------------------
# axes
# ---------------------------------------------------------------------------
def axis(start, direction, length, r0, r1, tortuosity, rng):
    """A smooth random axis from ``start`` leaving along ``direction``.

    The offset from the straight line is a sum of sin^2 modes in two normal directions
    with different random amplitudes (out-of-plane turns); it has zero slope at both ends,
    so the branch leaves and arrives along ``direction``. The bend radius is kept above
    2.5 local radii (the tube never folds onto itself).
    """
    d = unit(direction)
    n = max(4, int(np.ceil(length / (AXIS_STEP * min(r0, r1)))))
    s = np.linspace(0.0, length, n + 1)
    u = s / length
    e1 = perpendicular(d, rng)
    e2 = np.cross(d, e1)
    k = np.arange(1, 4)[:, None]
    modes = np.sin(np.pi * k * u) ** 2
    amp = rng.standard_normal((2, 3)) * tortuosity * length / (4.0 * k.ravel())
    off = amp @ modes
    rad = np.linspace(r0, r1, n + 1)
    for _ in range(6):
        pts = start + s[:, None] * d + off[0][:, None] * e1 + off[1][:, None] * e2
        if n < 3 or _max_bend(pts, rad) < 0.4:
            break
        off *= 0.6
    return pts, rad


def _max_bend(pts, rad) -> float:
    """Largest curvature x radius along a polyline."""
    d = np.diff(pts, axis=0)
    seg = np.linalg.norm(d, axis=1)
    t = d / seg[:, None]
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", t[:-1], t[1:]), -1, 1))
    return float(np.max(ang / (0.5 * (seg[:-1] + seg[1:])) * rad[1:-1]))


def straight(a, b, r0, r1):
    """Straight axis from ``a`` to ``b``."""
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / (AXIS_STEP * min(r0, r1)))))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + t * (b - a), np.linspace(r0, r1, n + 1)


def murray_split(r0, n, asymmetry, rng):
    """Radii of ``n`` daughters with r0^3 = sum r_i^3; weights drawn in [1 - asymmetry, 1]."""
    w = rng.uniform(1.0 - asymmetry, 1.0, n)
    return r0 * w / np.sum(w ** 3) ** (1 / 3)


def murray_angles(r0, r1, r2):
    """Optimal branching angles (radians) of daughters r1, r2 from the parent direction."""
    c1 = (r0 ** 4 + r1 ** 4 - r2 ** 4) / (2 * r0 ** 2 * r1 ** 2)
    c2 = (r0 ** 4 + r2 ** 4 - r1 ** 4) / (2 * r0 ** 2 * r2 ** 2)
    return float(np.arccos(np.clip(c1, -1, 1))), float(np.arccos(np.clip(c2, -1, 1)))


# ---------------------------------------------------------------------------
# growth
# ---------------------------------------------------------------------------
def _children_layout(t, plane, r0, p, junction_feature, rng):
    """Radii, directions and the feature of the daughters of one junction."""
    if junction_feature in ("trifurcation", "nfurcation"):
        n = 3 if junction_feature == "trifurcation" else int(rng.integers(4, 6))
        radii = murray_split(r0, n, 0.4, rng)
        spread = np.radians(rng.uniform(45, 65))
        angles = np.linspace(-spread, spread, n) + np.radians(rng.normal(0, 3, n))
        tilt = np.radians(rng.normal(0, 4, n)) if n > 3 else np.array([0.0, np.radians(rng.uniform(30, 60)), 0.0])
        side = np.cross(t, plane)
        dirs = [unit(rotate_towards(t, plane, a) + np.tan(b) * side) for a, b in zip(angles, tilt)]
        return radii, dirs
    alpha = rng.uniform(1.0 - p["asymmetry"], 1.0)
    r1 = r0 / (1 + alpha ** 3) ** (1 / 3)
    radii = np.array([r1, alpha * r1])
    if junction_feature == "acute_angle":
        th = np.radians(rng.uniform(6, 11, 2))
    else:
        th = np.array(murray_angles(r0, *radii)) + np.radians(rng.normal(0, p["angle_noise_deg"], 2))
        th = np.clip(th, np.radians(15), np.radians(95))
    return radii, [rotate_towards(t, plane, th[0]), rotate_towards(t, -plane, th[1])]


def grow(p: dict, rng, origin=np.zeros(3), direction=(0, 0, 1.0), root_radius=None) -> Tree:
    """Grow one tree (breadth first) with the junction features of ``p['pending']``.

    Parameters
    ----------
    p : dict
        Morphometry (``root_radius``, ``generations``, ``min_radius``, ``length_ratio``
        (min, max) in radii, ``taper``, ``tortuosity``, ``asymmetry``, ``angle_noise_deg``)
        and ``pending``: junction features still to place (consumed in order).
    """
    tree = Tree()
    r_root = root_radius or p["root_radius"]
    plane0 = perpendicular(unit(direction), rng)
    queue = [(np.asarray(origin, float), unit(direction), r_root, 0, -1, 0, plane0, None, [])]
    placed_at = []  # (junction branch, feature, daughters) of the junction features
    while queue:
        start, d, r, gen, parent, at, plane, forced_len, keep_out = queue.pop(0)
        r_end = r * rng.uniform(*p["taper"])
        pending = p["pending"]
        will_split = gen < p["generations"] and r_end * 0.75 >= p["min_radius"]
        feature = pending[0] if will_split and pending else None
        placed = False
        for _ in range(8):
            L = forced_len if forced_len is not None else max(rng.uniform(*p["length_ratio"]) * r,
                                                               max((kr + 3 * r for _, kr in keep_out), default=0.0))
            pts, rad = axis(start, d, L, r, r_end, p["tortuosity"] * (forced_len is None), rng)
            if parent < 0 or tree.clear_of(pts, rad, keep_out):
                placed = True
                break
            d = unit(d + 0.3 * rng.standard_normal(3))
        if not placed:
            continue
        tree.branches.append(Branch(pts, rad, parent, at))
        b = len(tree.branches) - 1
        if not will_split:
            continue
        if feature is not None:
            pending.pop(0)
        t = tree.branches[b].tangent(len(pts) - 1)
        # the next branching plane turns out of the previous one (3-D trees)
        phi = np.radians(rng.normal(90, 30))
        plane = unit(np.cos(phi) * (plane - (plane @ t) * t) + np.sin(phi) * np.cross(t, plane))
        radii, dirs = _children_layout(t, plane, r_end, p, feature, rng)
        cosmin = max(float(dirs[i] @ dirs[j]) for i in range(len(dirs)) for j in range(i + 1, len(dirs)))
        sin_min = np.sqrt(max(1 - cosmin ** 2, 0.0)) if cosmin > 0 else 1.0
        ko = [(pts[-1], min(12 * r_end, 1.3 * (r_end + radii.max()) / max(sin_min, 0.1)))]
        close = feature == "close_junctions"  # its first daughter is short and branches again
        for k, (rc, dc) in enumerate(zip(radii, dirs)):
            flen = rng.uniform(0.8, 1.8) * r_end if close and k == 0 else None
            queue.append((pts[-1], dc, rc, gen + 1 if flen is None else gen, b, len(pts) - 1, plane, flen, ko))
        if feature is not None:
            placed_at.append((b, feature, len(dirs)))
    # a junction feature counts only where its daughters found room (a blocked daughter is
    # dropped); two junctions closer than 2 radii only where the short daughter branched again
    for b, feature, n in placed_at:
        kids = tree.end_children(b)
        if feature == "close_junctions":
            first = [k for k in kids if tree.branches[k].s[-1] < 2 * tree.branches[b].rad[-1]]
            ok = any(len(tree.end_children(k)) >= 2 for k in first)
        else:
            ok = len(kids) == n
        tree.features[feature] += int(ok)
    return tree


# ---------------------------------------------------------------------------
# features placed on a grown tree
# ---------------------------------------------------------------------------
def _pick_point(tree, rng, kinds=("vessel",), min_len=6.0, leaf=False, min_radius=0.0):
    """(branch, point index) in the middle of a long enough branch, or None."""
    cand = [k for k, b in enumerate(tree.branches) if b.kind in kinds and b.s[-1] >= min_len * b.rad.mean()
            and (not leaf or not tree.children(k)) and b.rad.min() >= min_radius]
    if not cand:
        return None
    b = int(rng.choice(cand))
    n = len(tree.branches[b].pts)
    return b, int(rng.integers(int(0.3 * n), max(int(0.3 * n) + 1, int(0.7 * n))))


def add_side_branch(tree, rng, kind, p) -> bool:
    """A side branch leaving a vessel's wall: ``side`` (radius ratio about 1:5) or ``stub``
    (radius 0.3-0.6 of the parent's, cut 1-2 of its radii beyond the parent's wall)."""
    for _ in range(10):
        # a 1:5 branch leaves one of the largest vessels (it stays above 0.7 x min_radius)
        got = _pick_point(tree, rng, min_radius=3.0 * p["min_radius"] if kind == "side" else 0.0)
        if got is None:
            return False
        b, i = got
        br = tree.branches[b]
        rp, t = br.rad[i], br.tangent(i)
        rs = rp / rng.uniform(4.5, 5.5) if kind == "side" else rp * rng.uniform(0.3, 0.6)
        L = rp + (rng.uniform(1, 2) * rs if kind == "stub" else rng.uniform(8, 14) * rs)
        d = rotate_towards(t, perpendicular(t, rng), np.radians(rng.uniform(55, 90)))
        if kind == "stub":
            pts, rad = straight(br.pts[i], br.pts[i] + L * d, rs, rs)
        else:
            pts, rad = axis(br.pts[i], d, L, rs, rs * 0.9, 0.5 * p["tortuosity"], rng)
        if tree.clear_of(pts, rad, [(br.pts[i], rp + 2 * rs)]):
            tree.branches.append(Branch(pts, rad, b, i, kind=kind))
            tree.features["large_ratio" if kind == "side" else "stub"] += 1
            return True
    return False


def add_loop(tree, rng) -> bool:
    """An anastomosis between the two daughters of a junction (a circle-of-Willis-like ring)."""
    js = [k for k in range(len(tree.branches)) if len(tree.end_children(k)) >= 2]
    rng.shuffle(js)
    for j in js:
        c1, c2 = tree.end_children(j)[:2]
        b1, b2 = tree.branches[c1], tree.branches[c2]
        i1, i2 = int(rng.uniform(0.5, 0.75) * (len(b1.pts) - 1)), int(rng.uniform(0.5, 0.75) * (len(b2.pts) - 1))
        p1, p2 = b1.pts[i1], b2.pts[i2]
        rl = rng.uniform(0.5, 0.7) * min(b1.rad[i1], b2.rad[i2])
        if np.linalg.norm(p2 - p1) < 2.4 * (b1.rad[i1] + b2.rad[i2]) + 2 * rl:
            continue
        J = b1.pts[0]
        mid = 0.5 * (p1 + p2)
        ctrl = mid + 0.4 * (mid - J)
        n = max(4, int(np.ceil((np.linalg.norm(ctrl - p1) + np.linalg.norm(p2 - ctrl)) / (0.35 * rl))))
        u = np.linspace(0, 1, n + 1)[:, None]
        pts = (1 - u) ** 2 * p1 + 2 * u * (1 - u) * ctrl + u ** 2 * p2
        rad = np.full(len(pts), rl)
        ko = [(p1, b1.rad[i1] + 2.5 * rl), (p2, b2.rad[i2] + 2.5 * rl)]
        if tree.clear_of(pts, rad, ko, skip=()):
            tree.branches.append(Branch(pts, rad, c1, i1, end_on=(c2, i2), kind="loop"))
            tree.features["loop"] += 1
            return True
    return False


def add_kissing(tree, rng) -> bool:
    """A straight branch from one vessel that passes another at touching distance (gap
    -0.15 .. +0.05 of its radius): the surfaces meet, the skeletons do not."""
    P, R, B = tree.points()
    kd = cKDTree(P)
    for _ in range(40):
        q = int(rng.integers(len(P)))
        y = int(B[q])
        near = set(tree.children(y)) | {y, tree.branches[y].parent} | {c for k in tree.children(y) for c in tree.children(k)}
        cand = [a for a in kd.query_ball_point(P[q], 12 * R[q]) if B[a] not in near and np.linalg.norm(P[a] - P[q]) > 4 * R[q]]
        if not cand:
            continue
        a = int(rng.choice(cand))
        x = int(B[a])
        ia = int(np.argmin(np.linalg.norm(tree.branches[x].pts - P[a], axis=1)))
        rk = rng.uniform(0.5, 0.8) * min(R[a], R[q])
        target = R[q] + rk + rng.uniform(-0.15, 0.05) * rk
        w = P[q] - P[a]
        D = np.linalg.norm(w)
        beta = np.arcsin(min(target / D, 0.95))
        for _ in range(8):
            dirn = rotate_towards(unit(w), perpendicular(unit(w), rng), beta)
            end = P[a] + (D * np.cos(beta) + rng.uniform(3, 6) * rk) * dirn
            pts, rad = straight(P[a], end, rk, rk)
            Py, Ry = tree.branches[y].pts, tree.branches[y].rad
            dd = np.linalg.norm(pts[:, None] - Py[None], axis=2) - rad[:, None] - Ry[None]
            gap = dd.min()
            if abs(gap - (target - R[q] - rk)) > 0.12 * rk:
                continue
            if tree.clear_of(pts, rad, [(P[a], R[a] + 2 * rk), (Py[np.argmin(dd.min(axis=0))], Ry.max() + 3 * rk)]):
                tree.branches.append(Branch(pts, rad, x, ia, kind="kissing"))
                tree.features["kissing"] += 1
                return True
    return False


def add_aneurysm(tree, rng, where) -> bool:
    """A saccular aneurysm at a bifurcation apex (``apex``) or on a vessel's side wall
    (``side``); its skeleton is a two-segment branch into the sac centre."""
    for _ in range(12):
        if where == "apex":
            js = [k for k in range(len(tree.branches)) if len(tree.end_children(k)) >= 2 and tree.branches[k].kind == "vessel"]
            if not js:
                return False
            b = int(rng.choice(js))
            br = tree.branches[b]
            i = len(br.pts) - 1
            r, t = br.rad[i], br.tangent(i)
            R = rng.uniform(1.0, 1.6) * r
            c = br.pts[i] + t * (0.5 * r + 0.9 * R)
            neck = br.pts[i] + t * 0.5 * r
            skip = {b, *tree.children(b)}
        else:
            got = _pick_point(tree, rng)
            if got is None:
                return False
            b, i = got
            br = tree.branches[b]
            r, t = br.rad[i], br.tangent(i)
            m = perpendicular(t, rng)
            R = rng.uniform(1.0, 1.8) * r
            c = br.pts[i] + m * (r + 0.55 * R)
            neck = br.pts[i] + m * 0.9 * r
            skip = {b}
        P, Rp, _ = tree.points(skip)
        if len(P) and np.any(np.linalg.norm(P - c, axis=1) < R + CLEAR * Rp + 0.3 * r):
            continue
        if any(np.linalg.norm(c - s[0]) < R + s[1] + r for s in tree.sacs):
            continue
        pts = np.array([br.pts[i], neck, c])
        tree.branches.append(Branch(pts, np.array([r, 0.8 * r, R]), b, i, kind="aneurysm", tags={1: ["neck"], 2: ["aneurysm"]}))
        tree.sacs.append((c, R, 0.3 * r))
        tree.features[f"aneurysm_{where}"] += 1
        return True
    return False


def modulate_radius(tree, rng, feature, min_radius=0.0) -> bool:
    """Stenosis (50-80 % narrowing), fusiform dilatation (+50-100 %) or a sudden radius jump
    along one vessel of radius >= ``min_radius``."""
    for _ in range(10):
        got = _pick_point(tree, rng, leaf=feature == "radius_jump", min_len=5.0, min_radius=min_radius)
        if got is None:
            return False
        b, i = got
        br = tree.branches[b]
        s = br.s - br.s[i]
        r = br.rad[i]
        if feature == "radius_jump":
            ramp = np.clip(s / (0.3 * r) + 0.5, 0, 1)
            factor = 1 + (rng.uniform(0.55, 0.7) - 1) * ramp
        else:
            w = rng.uniform(2, 4) * r if feature == "stenosis" else rng.uniform(3, 5) * r
            bump = np.where(np.abs(s) < w, 0.5 * (1 + np.cos(np.pi * s / w)), 0.0)
            amp = -rng.uniform(0.5, 0.8) if feature == "stenosis" else rng.uniform(0.5, 1.0)
            factor = 1 + amp * bump
        new = br.rad * factor
        if feature == "fusiform":
            ends = [(br.pts[0], 3 * br.rad[0]), (br.pts[-1], 3 * br.rad[-1])]
            if not tree.clear_of(br.pts, new, ends, skip={b, *tree.children(b)}):
                continue
        br.rad = new
        br.tags.setdefault(i, []).append(feature)
        tree.features[feature] += 1
        return True
    return False


# ---------------------------------------------------------------------------
# skeleton
# ---------------------------------------------------------------------------
def skeleton_of(tree: Tree):
    """The true skeleton: nodes (xyz, radius, tags) every ~NODE_SPACING radii along each
    axis, with nodes at every junction, attachment and feature point.

    Returns
    -------
    xyz : (n, 3) ndarray
    radius : (n,) ndarray
    tags : list of list of str
    edges : (e, 2) ndarray
    """
    keys = [set([0, len(b.pts) - 1]) | set(b.tags) for b in tree.branches]
    for b in tree.branches:
        if b.parent >= 0:
            keys[b.parent].add(b.parent_at)
        if b.end_on is not None:
            keys[b.end_on[0]].add(b.end_on[1])
    index, xyz, rad, tags, edges = {}, [], [], [], []

    def node(k, i):
        br = tree.branches[k]
        if i == 0 and br.parent >= 0:
            return node(br.parent, br.parent_at)
        if i == len(br.pts) - 1 and br.end_on is not None:
            return node(*br.end_on)
        if (k, i) not in index:
            index[(k, i)] = len(xyz)
            xyz.append(br.pts[i])
            rad.append(br.rad[i])
            tags.append(["vessel"] + ([br.kind] if br.kind not in ("vessel", "aneurysm") else []) + br.tags.get(i, []))
        return index[(k, i)]

    for k, br in enumerate(tree.branches):
        ks = sorted(keys[k])
        s = br.s
        chain = [ks[0]]
        for a, c in zip(ks[:-1], ks[1:]):
            if br.kind != "aneurysm":
                m = max(1, int(round((s[c] - s[a]) / (NODE_SPACING * br.rad[a:c + 1].mean()))))
                inner = np.searchsorted(s, s[a] + (s[c] - s[a]) * np.arange(1, m) / m)
                chain += [int(i) for i in inner if a < i < c]
            chain.append(c)
        ids = [node(k, i) for i in chain]
        edges += [(u, v) for u, v in zip(ids[:-1], ids[1:]) if u != v]
    return np.array(xyz), np.array(rad), tags, np.array(edges, dtype=np.int64).reshape(-1, 2)
