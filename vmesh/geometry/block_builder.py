"""Assemble a conforming hexahedral block structure from a skeleton and a signed distance.

Method (see :mod:`vmesh.geometry.cross_sections` for the kernels)
----------------------------------------------------------------
1. **Junctions.** Every node with three or more neighbours gets a reference line
   ``(c, u)``; its neighbours are ordered around ``u`` and the space around it is split by
   half-planes through the line, one between each pair of consecutive neighbours. Each
   half-plane carries a *half cross-section* (half O-grid) whose outer corners are found by
   casting rays from the junction node within the half-plane; the diameter on the line is
   shared by all of them. Each half-plane may be rotated about ``u``: by default the
   rotation keeping the half-section closest to the junction node on average, among those
   that leave the neighbouring branches room for their first blocks.
2. **Branches.** The skeleton is cut into branches between junctions and endpoints
   (cycles without junctions are branches that close on themselves). Every other node gets
   a full cross-section: the bisecting plane of its two segments, the cap plane at an open
   end, the plane normal to the segment at a closed end (moved back from the endpoint to
   about the dome's centre; the dome beyond it is filled by a half-ball O-grid whose
   boundary layer continues the wall's). Near a junction, sections that would still reach
   into the other branches (rays much longer than the branch radius) or sit behind the
   half-sections' reach are moved along the branch until they are clear.
3. **Frames.** The reference direction of each section is transported along its branch
   by rotation-minimising frames (double reflection) from one end; the twist left at the
   other end (modulo the template's symmetry) is spread evenly by arc length.
4. **Blocks.** Consecutive sections of a branch are joined quad by quad into hexahedra.
   A branch's end section at a junction is the union of its two adjacent half-sections,
   folded along ``u``; neighbouring branches share the half-section vertices, so the
   structure is conforming by construction.
5. **Validity.** Every block must have positive Jacobians at its eight corners. Failing
   blocks are fixed by moving sections further from junctions, re-rotating junction
   half-planes, straightening tilted planes and shrinking the core; a block that stays
   invalid raises :class:`~vmesh.errors.MeshingError` naming its skeleton node.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..blocks import (
    AXIS_ALONG,
    AXIS_LAYER,
    AXIS_RING,
    FACE_INTERIOR,
    FACE_WALL,
    HEX_FACES,
    LAYER_BOUNDARY,
    LAYER_CORE,
    LAYER_RING,
    BlockStructure,
)
from ..errors import MeshingError
from ..skeleton import Skeleton
from . import cross_sections as cs

JUNCTION, OPEN, CLOSED, CYCLE = "junction", "open", "closed", "cycle"


@dataclass
class BlockOptions:
    """Parameters of :func:`build_blocks` (see the filter ``build_block_structure``)."""

    blocks_around: int = 8
    core_size: float = 0.3
    layer_thickness: float = 0.3
    plane_bias: float = 1.0
    junction_rotation: str = "closest"  # or "bisector"
    rotation_range: float = 0.6
    rotation_candidates: int = 9
    max_out_of_plane: float = 60.0  # degrees
    min_branch_gap: float = 12.0  # degrees
    split_nonplanar: bool = True
    max_retopology_tries: int = 8  # whole rebuilds with merged or split junctions
    clear_ray_factor: float = 1.8
    junction_margin: float = 0.3  # × branch radius, between half-sections and the first section
    cap_distance: float = 1.0  # × radius
    dome_depth: float = 1.0  # wall distance ahead of a closed end's section, × its mean wall distance
    dome_max_retreat: float = 1.5  # × endpoint radius
    max_fix_rounds: int = 16
    wall_quality: float = 0.05  # least scaled Jacobian of boundary-layer blocks with projected wall faces
    good_wall_quality: float = 0.3  # projected quality at which a junction end's margin stops growing
    wall_margins: tuple = (0.0, 0.5, 1.0, 2.0)  # extra margins tried at folding junction ends (× radius)
    relieve_wall_folds: bool = True  # re-place junction sections where boundary-layer blocks would fold (fill-judged)
    junction_centre: float = 1.0  # how far half-sections' common line moves from the node to the wall's centre (0: at the node)


@dataclass
class _Junction:
    node: int
    center: np.ndarray
    radius: float
    u: np.ndarray
    p: np.ndarray  # basis of the plane ⟂ u
    q: np.ndarray
    neighbors: np.ndarray  # ordered around u
    branch_angle: np.ndarray  # (m,) ordered
    separator: np.ndarray  # (m,) base angles (bisectors), separator h between neighbors h and h+1
    gap: np.ndarray  # (m,)
    psi: np.ndarray  # (m,) chosen rotation of each separator
    ends: list = field(default_factory=list)  # (branch, side) per ordered neighbour
    allowed: list = field(default_factory=list)  # per separator: bool mask over candidates
    spine_ids: np.ndarray | None = None  # (nv,) global ids of spine vertices (-1 elsewhere)
    half_ids: np.ndarray | None = None  # (m, nv) global ids of upper-half vertices per separator

    def separator_dir(self, h, psi=None) -> np.ndarray:
        ang = self.separator[h] + (self.psi[h] if psi is None else psi)
        return np.cos(ang)[..., None] * self.p + np.sin(ang)[..., None] * self.q


@dataclass
class _Branch:
    nodes: np.ndarray  # (K+1,)
    edges: np.ndarray  # (K,)
    kinds: list  # [start kind, end kind]
    caps: list  # cap id per end (0 none)
    arc: np.ndarray  # (K+1,) arc length at nodes
    s: np.ndarray  # (K+1,) section positions (arc length)
    margin: np.ndarray = field(default_factory=lambda: np.zeros(2))  # extra clearance per end (× radius)
    straighten: np.ndarray | None = None  # (K+1,) blend of section normals towards the chord


def build_blocks(
    skeleton: Skeleton,
    distance,
    caps=None,
    options: BlockOptions | None = None,
    bad_blocks_path=None,
    warn=None,
    progress=None,
    project=None,
    intersect_lines=None,
) -> BlockStructure:
    """Build the block structure of a vessel.

    Parameters
    ----------
    skeleton : Skeleton
        Centerline graph with radii, coarsely resampled (node spacing ~1-2 radii).
    distance : callable
        ``distance(points (n, 3)) -> (n,)`` signed distance, positive inside the vessel.
    caps : list of vmesh.caps.Cap, optional
        Flat open ends. Endpoints near a cap end on its plane with their end faces named
        after it; endpoints without a cap are closed (a cap of blocks fills the dome). Without
        any caps every endpoint is an open end, named by decreasing radius.
    options : BlockOptions
    bad_blocks_path : path, optional
        Where invalid blocks are written (VTU) before failing.
    warn, progress : callable, optional
        ``warn(message)`` and ``progress(fraction, message)``.
    project : callable, optional
        ``project(points) -> closest wall points``: when given, boundary-layer blocks are
        also checked with their wall faces projected onto the wall and thickened where they
        would fold (:func:`projected_wall_quality`).
    intersect_lines : callable, optional
        Line casts on the same surface
        (:meth:`~vmesh.geometry.sdf.SignedDistance.intersect_lines`): the section rays
        then find the wall by one cast each instead of bisecting ``distance``
        (:func:`~vmesh.geometry.cross_sections.cast_rays`).

    Returns
    -------
    BlockStructure
        With ``info`` holding ``max_twist_deg``, ``fixes`` and per-junction details.
    """
    options = options or BlockOptions()
    # Each try either succeeds or fails with what might help: splitting n-furcations
    # (alternative pairings in turn) or merging two junctions too close for their own
    # half-sections. Tries are depth-first and bounded; the first failure is reported.
    queue = [(skeleton, [])]
    first = None
    tries = 0
    while queue and tries < options.max_retopology_tries:
        sk, notes = queue.pop(0)
        tries += 1
        try:
            blocks = _Builder(sk, distance, caps, options, warn, progress, project, intersect_lines).run()
        except _Failure as failure:
            first = first or failure
            queue[:0] = _retopology_options(failure, notes, distance, options)
            continue
        except MeshingError:
            if first is None:
                raise  # the skeleton as given is beyond the scheme: say why
            continue  # a changed skeleton that does not work either
        for note in notes:
            if warn:
                warn(note)
        blocks.info["fixes"][:0] = notes
        return blocks
    raise first.error(bad_blocks_path, tries)


def _retopology_options(failure: "_Failure", notes: list, distance, options: BlockOptions) -> list:
    """Skeletons to try after ``failure``, most promising first: with two junctions merged
    (when the branch between them has no room for their half-sections), or with the
    failing n-furcations split into 3-junctions, one pairing of branches after another."""
    out = []
    sk = failure.skeleton
    if options.split_nonplanar:
        for a, b in failure.crowded:
            merged, node = merge_junction_pair(sk, a, b)
            out.append((merged, notes + [f"merged junction nodes {a} and {b} (their half cross-sections left the branch between them no room) into node {node}"]))
        if failure.nfurcations:
            degree = int(max(sk.degrees[c] for c in failure.nfurcations))
            for rank in range(degree * (degree - 1) // 2):
                split = split_nonplanar_junctions(sk, failure.nfurcations, distance=distance, rank=rank)
                out.append((split, notes + [f"split junction node(s) {failure.nfurcations} into 3-junctions (pairing {rank + 1}) after their blocks stayed invalid"]))
    return out


class _Failure(Exception):
    """Blocks that stay invalid, with what a changed skeleton might fix."""

    def __init__(self, message, blocks, bad, skeleton, nfurcations, crowded, hint):
        super().__init__(message)
        self.message, self.blocks, self.bad = message, blocks, bad
        self.skeleton, self.nfurcations, self.crowded, self.hint = skeleton, nfurcations, crowded, hint

    def error(self, path, tries: int = 1) -> MeshingError:
        written = ""
        if path is not None:
            try:
                written = f"; the {len(self.bad)} invalid block(s) are in {write_bad_blocks(self.blocks, self.bad, path)}"
            except Exception as exc:  # the error itself matters more than the picture
                written = f" (could not write the invalid blocks: {exc})"
        tried = f" ({tries - 1} changed skeleton(s) tried too)" if tries > 1 else ""
        return MeshingError(self.message + written + tried + self.hint)


# ---------------------------------------------------------------------------
# skeleton preparation
# ---------------------------------------------------------------------------
def split_nonplanar_junctions(skeleton: Skeleton, nodes, length: float = 1.2, distance=None, inside: float = 0.5, rank: int = 0) -> Skeleton:
    """Split junctions into chains of 3-junctions.

    At each node of degree ``m > 3`` two neighbours are moved onto a new node placed
    ``length × radius`` along their mean direction and joined to the original node by a
    new segment; repeated until every node has at most three neighbours. Tags are
    inherited. With ``distance`` (signed, positive inside) the new node goes no further
    than where it is still ``inside × radius`` inside the vessel, and the pairs are ranked
    by how deep inside their new node lies (a node pushed into the wall between two
    ostia makes blocks that cannot be fixed), then by how close their directions are;
    without it by closeness alone. Nearly opposite pairs come last.

    Parameters
    ----------
    skeleton : Skeleton
    nodes : sequence of int
        Junctions to split.
    length : float
        Distance of a new node from its junction (× the junction radius).
    distance : callable, optional
        Signed distance, positive inside.
    inside : float
        Least depth of a new node (× the junction radius).
    rank : int
        Which pair to split off at each step (0: the best ranked; alternatives when the
        best one's blocks cannot be made valid).

    Returns
    -------
    Skeleton
        The split skeleton (the original nodes keep their numbers).
    """
    sk = skeleton
    pts = list(sk.points)
    rad = list(sk.radii)
    ntags = list(sk.node_tags)
    edges = [tuple(e) for e in sk.edges.tolist()]
    etags = list(sk.edge_tags)
    todo = [int(n) for n in nodes]
    while todo:
        c = todo.pop()
        inc = [k for k, e in enumerate(edges) if c in e]
        if len(inc) <= 3:
            continue
        nb = [edges[k][0] if edges[k][1] == c else edges[k][1] for k in inc]
        d = cs.unit(np.asarray([pts[j] for j in nb]) - pts[c])
        pi, pj = np.triu_indices(len(nb), 1)
        w = cs.unit(d[pi] + d[pj])  # (pairs, 3)
        t = np.full(len(pi), length * rad[c])
        depth = np.zeros(len(pi))
        if distance is not None:
            ts = np.linspace(0.25, 1.0, 16) * length * rad[c]
            probe = np.asarray(pts[c]) + ts[None, :, None] * w[:, None, :]
            ok = np.asarray(distance(probe.reshape(-1, 3))).reshape(len(pi), -1) >= inside * rad[c]
            t = np.where(ok.any(axis=1), np.where(ok, ts[None, :], 0.0).max(axis=1), ts[0])
            depth = np.asarray(distance(np.asarray(pts[c]) + t[:, None] * w)) / rad[c]
        closeness = np.sum(d[pi] * d[pj], axis=1)
        # deeper first (to 1 % of the radius), then closer directions; nearly opposite
        # branches have no mean direction to put a node on: last
        degenerate = np.linalg.norm(d[pi] + d[pj], axis=1) < 0.2
        order = np.lexsort((-closeness, -np.round(depth, 2), degenerate))
        best = order[min(int(rank), len(order) - 1)]
        i, j = int(pi[best]), int(pj[best])
        new = len(pts)
        pts.append(np.asarray(pts[c]) + t[best] * w[best])
        rad.append(rad[c])
        ntags.append(ntags[c])
        for k in (inc[i], inc[j]):
            a, b = edges[k]
            edges[k] = (new if a == c else a, new if b == c else b)
        edges.append((c, new))
        etags.append(tuple(sorted(set(etags[inc[i]]) | set(etags[inc[j]]))))
        todo.append(c)
    return Skeleton(np.asarray(pts), np.asarray(rad), np.asarray(edges), ntags, etags, name=sk.name)


def merge_junction_pair(skeleton: Skeleton, a: int, b: int) -> tuple[Skeleton, int]:
    """Merge junctions ``a`` and ``b`` and the branch between them into one junction.

    The merged junction sits at the mean of the two with the larger radius; the other
    nodes keep their order.

    Returns
    -------
    skeleton : Skeleton
    node : int
        The merged junction's number in the new skeleton.
    """
    from .skeleton_ops import branch_paths, contract_nodes

    sk = skeleton
    path = next(p for p in branch_paths(sk.n_nodes, sk.edges) if {int(p[0]), int(p[-1])} == {a, b})
    keep = min(a, b)
    group = np.arange(sk.n_nodes)
    group[np.asarray(path)] = keep
    labels = np.unique(group)
    positions = sk.points[labels].copy()
    positions[np.searchsorted(labels, keep)] = 0.5 * (sk.points[a] + sk.points[b])
    merged = contract_nodes(sk, group, positions)
    return merged, int(np.searchsorted(labels, keep))


def endpoint_caps(points: np.ndarray, radii: np.ndarray, endpoints: np.ndarray, caps, cap_distance: float = 1.0) -> dict:
    """Match endpoints to caps: ``{endpoint node: cap}`` for endpoints within
    ``cap_distance × max(node radius, cap radius)`` of a cap centre (nearest first, one
    endpoint per cap)."""
    if not caps or len(endpoints) == 0:
        return {}
    centers = np.asarray([c.center for c in caps], float)
    crad = np.asarray([c.radius for c in caps], float)
    d = np.linalg.norm(points[endpoints][:, None, :] - centers[None, :, :], axis=2)
    limit = cap_distance * np.maximum(radii[endpoints][:, None], crad[None, :])
    pairs = sorted((d[i, j], i, j) for i, j in zip(*np.nonzero(d <= limit)))
    out, used_e, used_c = {}, set(), set()
    for _, i, j in pairs:
        if i in used_e or j in used_c:
            continue
        out[int(endpoints[i])] = caps[j]
        used_e.add(i)
        used_c.add(j)
    return out


def redistribute_sections(arc: np.ndarray, lo: float, hi: float, min_spacing: float = 0.6) -> tuple[np.ndarray, bool]:
    """Move the interior sections of a branch into ``[lo, hi]``.

    Sections closer to the start than ``lo`` are pushed beyond it together with as many
    following ones as needed to keep their spacing at least ``min_spacing`` times the
    branch's mean spacing (evenly spaced, the first at ``lo``); likewise from the end. When
    the pushes meet, all interior sections are spread evenly over ``[lo, hi]``.

    Returns
    -------
    s : (K+1,) new positions (ends unchanged)
    ok : False when ``lo >= hi`` with interior sections to place.
    """
    s = np.asarray(arc, float).copy()
    K = len(s) - 1
    if K < 2:
        return s, True
    if lo >= hi:
        return s, False
    h = (s[-1] - s[0]) / K * min_spacing

    def push(x, lim):
        m0 = int(np.sum(x[1:-1] < lim))
        if m0 == 0:
            return x
        for m in range(m0, K):
            end = x[m + 1]
            if (end - lim) / m >= h or m + 1 == K:
                break
        x = x.copy()
        x[1 : m + 1] = lim + np.arange(m) * (end - lim) / m
        return x

    s = push(s, lo)
    s = (s[-1] + s[0]) - push((s[-1] + s[0]) - s[::-1], (s[-1] + s[0]) - hi)[::-1]
    inner = s[1:-1]
    if np.any(np.diff(s) <= 0) or inner.min() < lo - 1e-9 or inner.max() > hi + 1e-9:
        n = K - 1
        s[1:-1] = (lo + hi) / 2 if n == 1 else np.linspace(lo, hi, n)
    return s, True


def polyline_at(points: np.ndarray, arc: np.ndarray, s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position on a polyline and linearly interpolated per-node ``values`` at arc lengths ``s``."""
    s = np.clip(s, arc[0], arc[-1])
    k = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(arc) - 2)
    t = ((s - arc[k]) / np.maximum(arc[k + 1] - arc[k], 1e-300))[:, None]
    pos = points[k] * (1 - t) + points[k + 1] * t
    val = values[k] * (1 - t.reshape((-1,) + (1,) * (values.ndim - 1))) + values[k + 1] * t.reshape((-1,) + (1,) * (values.ndim - 1))
    return pos, val


# ---------------------------------------------------------------------------
# the builder
# ---------------------------------------------------------------------------
class _Builder:
    def __init__(self, skeleton: Skeleton, distance, caps, options: BlockOptions, warn, progress, project=None, intersect_lines=None):
        self.opt = options
        self.sdf = distance
        self.intersect_lines = intersect_lines
        self.project = project
        self.caps = list(caps or [])
        self.warn = warn or (lambda msg: None)
        self.tick = progress or (lambda f, m="": None)
        self.template = cs.o_grid_template(options.blocks_around)
        self.sk = skeleton
        self.fixes: list[str] = []
        self.core_scale: dict = {}
        self.layer_scale: dict = {}
        self.lookahead: dict = {}

    # -- entry ------------------------------------------------------------------
    def run(self) -> BlockStructure:
        self.check_skeleton()
        self.tick(0.05, "junctions")
        self.split_if_needed()
        self.pos = self.sk.points.copy()
        self.make_branches()
        self.build_junctions()
        self.classify_ends()
        self.tick(0.15, "junction planes")
        self.moves = {}
        self.choose_rotations()
        self.tick(0.3, "sections")
        self.place_sections()
        blocks = None
        for round_ in range(self.opt.max_fix_rounds + 1):
            self.tick(0.4 + 0.5 * round_ / (self.opt.max_fix_rounds + 1), "blocks")
            blocks = self.assemble()
            J = blocks.corner_jacobians()
            bad = np.flatnonzero(J.min(axis=1) <= 0)
            if len(bad) == 0:
                break
            if round_ == self.opt.max_fix_rounds or not self.fix(bad, J):
                self.fail(blocks, bad)
        if self.project is not None:
            blocks = self.thicken_layers(blocks)
            if self.opt.relieve_wall_folds:
                blocks = self.relieve_wall_folds(blocks)
            self.report_wall_folds(blocks)
        blocks.info.update(self.info)
        blocks.info["fixes"] = list(self.fixes)
        self.tick(1.0, "done")
        return blocks

    # -- 1. skeleton -------------------------------------------------------------
    def check_skeleton(self):
        sk = self.sk
        if sk.n_edges == 0:
            raise MeshingError("skeleton has no segments: nothing to build blocks along")
        if np.any(sk.edges[:, 0] == sk.edges[:, 1]):
            k = int(np.flatnonzero(sk.edges[:, 0] == sk.edges[:, 1])[0])
            raise MeshingError(f"skeleton segment {k} joins node {sk.edges[k, 0]} to itself")
        key = np.sort(sk.edges, axis=1)
        if len(np.unique(key, axis=0)) != len(key):
            raise MeshingError("skeleton has duplicate segments between the same two nodes")
        if not np.all(np.isfinite(sk.radii)) or np.any(sk.radii <= 0):
            bad = int(np.flatnonzero(~np.isfinite(sk.radii) | (sk.radii <= 0))[0])
            raise MeshingError(f"skeleton node {bad} has no positive radius (run estimate_radii)")
        length = np.linalg.norm(sk.points[sk.edges[:, 1]] - sk.points[sk.edges[:, 0]], axis=1)
        if np.any(length <= 1e-9 * max(1.0, sk.radii.max())):
            k = int(np.argmin(length))
            raise MeshingError(f"skeleton segment {k} between nodes {sk.edges[k, 0]} and {sk.edges[k, 1]} has zero length")
        deg = sk.degrees
        if np.any(deg >= 3) and not self.template.splittable:
            j = sk.junctions[:3].tolist()
            raise MeshingError(
                f"blocks_around = {self.opt.blocks_around} gives a 1 x 1 core without a grid line through its centre, "
                f"so junctions (nodes {j}) cannot be split into half cross-sections: use 6, 8 (default), 10 ... blocks around"
            )
        d = np.asarray(self.sdf(sk.points))
        inner = (deg >= 2) & (d <= 0)
        if inner.any():
            k = int(np.flatnonzero(inner)[0])
            raise MeshingError(
                f"skeleton node {k} lies outside the surface (signed distance {d[k]:.3g}); "
                f"{int(inner.sum())} node(s) outside: add clean_skeleton (outside='pull') and resample_skeleton with the sdf "
                "before build_block_structure, which bring grazing nodes inside and stop on a centerline of another vessel"
            )
        if np.any(deg == 0):
            self.warn(f"{int((deg == 0).sum())} isolated skeleton node(s) ignored")
        if sk.n_components > 1:
            self.warn(f"skeleton has {sk.n_components} components: the block structure will too")

    # -- 2. junctions ------------------------------------------------------------
    def junction_problem(self, c: int, d: np.ndarray):
        """The junction axis of node ``c`` with neighbour directions ``d``, or why the scheme cannot take it."""
        opt = self.opt
        u, gap, elev = cs.junction_axis(d, np.radians(opt.max_out_of_plane))
        if elev > np.radians(opt.max_out_of_plane):
            k = int(np.argmax(np.abs(d @ u)))
            return u, (k, f"one of its branches leaves the junction plane by {np.degrees(elev):.0f} degrees (more than max_out_of_plane = {opt.max_out_of_plane:g})")
        if gap < np.radians(opt.min_branch_gap):
            return u, (None, f"two of its branches are only {np.degrees(gap):.0f} degrees apart around the junction axis (less than min_branch_gap = {opt.min_branch_gap:g})")
        return u, None

    def split_if_needed(self):
        """With ``split_nonplanar``: split n-furcations (4+ branches) that are too far from planar
        into chains of 3-junctions. Other problems are reported by :meth:`build_junctions`."""
        if not self.opt.split_nonplanar:
            return
        sk = self.sk
        split = []
        for c in sk.junctions.tolist():
            nb = sk.neighbors(c)
            if len(nb) <= 3:
                continue
            _, problem = self.junction_problem(c, cs.unit(sk.points[nb] - sk.points[c]))
            if problem:
                split.append(c)
        if split:
            self.sk = split_nonplanar_junctions(sk, split, distance=self.sdf)
            self.fixes.append(f"split non-planar junction node(s) {split} into 3-junctions")
            self.warn(f"split non-planar junction node(s) {split} into 3-junctions")
            self.check_skeleton()

    def _branch_direction(self, bi: int, side: int, length: float) -> np.ndarray:
        """Unit direction from a branch end (its current position) to the point ``length``
        further along the branch's nodes (at least its first neighbour)."""
        br = self.branches[bi]
        nodes = br.nodes if side == 0 else br.nodes[::-1]
        P = self.sk.points[nodes]
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
        s = np.array([max(min(length, arc[-1]), arc[1])])
        target, _ = polyline_at(P, arc, s, np.zeros((len(P), 1)))
        return cs.unit(target[0] - self.pos[nodes[0]])

    def build_junctions(self, nodes=None):
        """Junction axes, neighbour order and separators (from the current positions), for
        all junctions or only ``nodes``."""
        sk = self.sk
        if nodes is None:
            self.junctions: dict[int, _Junction] = {}
        ends = {}
        for bi, br in enumerate(self.branches):
            for side in (0, 1):
                if br.kinds[side] == JUNCTION:
                    c = int(br.nodes[0] if side == 0 else br.nodes[-1])
                    ends.setdefault(c, []).append((bi, side))
        for c, lst in ends.items():
            if nodes is not None and c not in nodes:
                continue
            moved = float(np.linalg.norm(self.pos[c] - sk.points[c]))
            rc = float(sk.radii[c])
            # directions to the first neighbours; further along the branches when those are
            # nearly parallel (a junction node placed before the vessels really part)
            first = None
            for ahead in (0.0, 1.5, 2.0, 3.0, 4.0):
                length = max(moved + 0.5 * rc, ahead * rc) if (moved > 0 or ahead > 0) else 0.0
                d = np.stack([self._branch_direction(bi, side, length) for bi, side in lst])
                u, problem = self.junction_problem(c, d)
                if first is None:
                    first = problem
                if problem is None:
                    if ahead > 0 and c not in self.lookahead:
                        self.lookahead[c] = ahead
                        self.fixes.append(f"junction node {c}: branch directions taken {ahead:g} radii along its branches ({first[1]} at its first neighbours)")
                    break
            if problem:
                k, why = first
                m = len(lst)
                if k is not None:
                    nb = int(self.branches[lst[k][0]].nodes[1] if lst[k][1] == 0 else self.branches[lst[k][0]].nodes[-2])
                    why = why.replace("one of its branches", f"its branch towards node {nb}")
                hint = (
                    "; set split_nonplanar = true to split it into 3-junctions"
                    if m > 3
                    else "; move the junction node or resample the skeleton so that its branches spread around it"
                )
                raise MeshingError(f"junction at skeleton node {c} ({m} branches) is beyond the junction scheme: {why}{hint}")
            ang, p, q = cs.order_around(u, d)
            order, sep, gap = cs.separator_angles(ang)
            self.junctions[c] = _Junction(
                node=c, center=self._junction_centre(c, u, p, q, sep), radius=float(sk.radii[c]), u=u, p=p, q=q,
                neighbors=np.array([int(self.branches[bi].nodes[1] if side == 0 else self.branches[bi].nodes[-2]) for bi, side in lst])[order],
                branch_angle=ang[order], separator=sep, gap=gap, psi=np.zeros(len(lst)),
                ends=[lst[i] for i in order],
            )
            self.junctions[c].dirs = d[order]

    def _junction_centre(self, c: int, u, p, q, sep) -> np.ndarray:
        """Point of the junction's common line (the half-sections' spine).

        As vascularmd places a bifurcation's centre (Decroocq et al. 2023), the line goes
        through the mean of the wall points straight out along the separators (the apex
        of each crotch and the outer walls between branches), centred between the wall
        above and below along ``u``. A node far upstream of the apex would otherwise cast
        the crotch half-section as a long sliver that reaches along the daughters and
        folds their first boundary-layer blocks. ``junction_centre`` blends from the node
        (0) to that point (1); it stays at least half the node's radius inside."""
        o = self.pos[c].copy()
        w = float(self.opt.junction_centre)
        if w <= 0:
            return o
        rc = float(self.sk.radii[c])
        sd = np.cos(sep)[:, None] * p + np.sin(sep)[:, None] * q
        R = self.cast(np.repeat(o[None], len(sd), 0), sd, np.full(len(sd), rc))
        if not np.all(np.isfinite(R)):
            return o
        x = o + w * np.mean(R[:, None] * sd, axis=0)
        ud = self.cast(np.repeat(x[None], 2, 0), np.stack([u, -u]), np.full(2, rc))
        if np.all(np.isfinite(ud)):
            x = x + 0.5 * (ud[0] - ud[1]) * u
        if float(np.asarray(self.sdf(x[None]))[0]) < 0.5 * rc:
            return o
        return x

    # -- 3. branches -------------------------------------------------------------
    def make_branches(self):
        from .skeleton_ops import branch_paths, path_edge_ids

        sk = self.sk
        if not hasattr(self, "_paths"):
            paths = branch_paths(sk.n_nodes, sk.edges)
            self._paths = (paths, path_edge_ids(sk.n_nodes, sk.edges, paths))
        paths, eids = self._paths
        deg = sk.degrees
        old = getattr(self, "branches", None)
        self.branches: list[_Branch] = []
        for n, (nodes, edges) in enumerate(zip(paths, eids)):
            nodes = np.asarray(nodes)
            edges = np.asarray(edges)
            if nodes[0] == nodes[-1] and deg[nodes[0]] == 2:
                kinds = [CYCLE, CYCLE]
            else:
                kinds = [JUNCTION if deg[nodes[0]] >= 3 else "end", JUNCTION if deg[nodes[-1]] >= 3 else "end"]
                if kinds[0] != JUNCTION and kinds[1] == JUNCTION:
                    nodes, edges, kinds = nodes[::-1].copy(), edges[::-1].copy(), kinds[::-1]
            seg = np.linalg.norm(np.diff(self.pos[nodes], axis=0), axis=1)
            arc = np.r_[0.0, np.cumsum(seg)]
            br = _Branch(nodes, edges, kinds, [0, 0], arc, arc.copy(), straighten=np.zeros(len(nodes)))
            if old is not None:
                br.margin = old[n].margin
                br.straighten = old[n].straighten
            self.branches.append(br)

    def classify_ends(self):
        sk = self.sk
        ends = sk.endpoints
        self.cap_of = endpoint_caps(sk.points, sk.radii, ends, self.caps, self.opt.cap_distance)
        names = {FACE_WALL: "wall"}
        if not self.caps:
            # every endpoint is an open end, named by decreasing radius
            order = ends[np.argsort(-sk.radii[ends], kind="stable")]
            self.end_id = {int(e): k + 1 for k, e in enumerate(order.tolist())}
            for k, e in enumerate(order.tolist()):
                names[k + 1] = "inlet" if k == 0 else f"outlet_{k}"
        else:
            self.end_id = {e: cap.id for e, cap in self.cap_of.items()}
            for cap in self.cap_of.values():
                names[int(cap.id)] = cap.name
            unused = [c.name for c in self.caps if all(c is not v for v in self.cap_of.values())]
            if unused and not getattr(self, "_warned_caps", False):
                self.warn(f"no skeleton endpoint near cap(s) {', '.join(unused)}: those open ends are not meshed")
                self._warned_caps = True
        self.boundary_names = names
        for br in self.branches:
            for side in (0, 1):
                if br.kinds[side] in ("end", OPEN, CLOSED):
                    e = int(br.nodes[0] if side == 0 else br.nodes[-1])
                    if e in self.end_id:
                        br.kinds[side], br.caps[side] = OPEN, self.end_id[e]
                    else:
                        br.kinds[side] = CLOSED

    def _slack(self, bi: int) -> float:
        """Room left on a branch between two junctions once both half-sections are in."""
        br = self.branches[bi]
        L = float(np.linalg.norm(self.pos[br.nodes[-1]] - self.pos[br.nodes[0]])) if len(br.nodes) == 2 else br.arc[-1]
        return L - self._junction_reach(bi, 0) - self._junction_reach(bi, 1)

    def separate_junctions(self, bi: int) -> bool:
        """Move one end junction of a branch between two junctions away from the other.

        Each end is tried (half a branch radius along the branch, into the wedge of the
        junction's other branches, staying well inside and within 1.5 radii of its node);
        the move that leaves the branch most room is kept."""
        sk = self.sk
        br = self.branches[bi]
        if br.kinds != [JUNCTION, JUNCTION] or br.nodes[0] == br.nodes[-1]:
            return False
        rb = float(np.median(sk.radii[br.nodes]))
        base = self._slack(bi)
        best = None
        for side in (0, 1):
            c = int(br.nodes[0] if side == 0 else br.nodes[-1])
            other = int(br.nodes[-1] if side == 0 else br.nodes[0])
            w = cs.unit(self.pos[c] - self.pos[other])
            new = self.pos[c] + 0.5 * rb * w
            if np.linalg.norm(new - sk.points[c]) > 1.5 * sk.radii[c]:
                continue
            if float(np.asarray(self.sdf(new[None]))[0]) < 0.4 * sk.radii[c]:
                continue
            old_pos, old_j = self.pos[c].copy(), self.junctions[c]
            self.pos[c] = new
            try:
                self._rebuild_junction(c)
                gain = self._slack(bi) - base
            except MeshingError:
                gain = -np.inf
            self.pos[c] = old_pos
            self.junctions[c] = old_j
            self._rebuild_branches()
            if best is None or gain > best[0]:
                best = (gain, c, new)
        if best is None or best[0] <= 1e-9 * rb:
            return False
        _, c, new = best
        self.pos[c] = new
        self._rebuild_junction(c)
        self.moves[c] = float(np.linalg.norm(new - sk.points[c]))
        self.fixes.append(f"moved junction node {c} by {self.moves[c]:.3g} along its branch to node {int(br.nodes[0] if c == br.nodes[-1] else br.nodes[-1])}")
        return True

    def _rebuild_branches(self):
        self.make_branches()
        self.classify_ends()

    def _rebuild_junction(self, c: int):
        self._rebuild_branches()
        self.build_junctions({c})
        self.choose_rotations({c})

    # -- 4. junction half-planes --------------------------------------------------
    def _neighbour_room(self, j: _Junction) -> np.ndarray:
        """How far (along each ordered neighbour's branch) sections may be pushed."""
        room = np.empty(len(j.neighbors))
        for h, (bi, side) in enumerate(j.ends):
            br = self.branches[bi]
            L = br.arc[-1]
            other = br.kinds[1 - side]
            room[h] = (0.45 if other == JUNCTION else 0.8) * L if len(br.nodes) > 2 else 0.85 * L
        return room

    def _half_rays(self, j: _Junction, sdirs: np.ndarray) -> np.ndarray:
        """Ray lengths (k, nr) of half-sections with in-plane directions ``sdirs`` (k, 3);
        angles in (π, 2π) mirror the upper half, 0 and π are the spine."""
        t = self.template
        ang = t.ray_angles
        up = (ang > 1e-9) & (ang < np.pi - 1e-9)
        k = len(sdirs)
        e1 = np.repeat(j.u[None, :], k, axis=0)
        dirs = cs.ray_directions(e1, sdirs, ang[up])
        o = np.repeat(j.center[None, :], dirs.shape[0] * dirs.shape[1], axis=0)
        R_up = self.cast(o, dirs.reshape(-1, 3), np.full(len(o), j.radius)).reshape(k, -1)
        R = np.empty((k, len(ang)))
        R[:, up] = R_up
        idx_up = np.flatnonzero(up)
        lower = np.flatnonzero(ang > np.pi + 1e-9)
        mirror_of = cs.ray_index(t, cs._TWO_PI - ang[lower])
        pos = {int(v): n for n, v in enumerate(idx_up)}
        R[:, lower] = R_up[:, [pos[int(v)] for v in mirror_of]]
        spine = self.spine_rays(j)
        R[:, cs.ray_index(t, 0.0)] = spine[0]
        R[:, cs.ray_index(t, np.pi)] = spine[1]
        return R

    def spine_rays(self, j: _Junction) -> np.ndarray:
        o = np.repeat(j.center[None, :], 2, axis=0)
        return self.cast(o, np.stack([j.u, -j.u]), np.full(2, j.radius))

    def _half_vertices(self, j: _Junction, sdirs: np.ndarray, R: np.ndarray, core=None, layer=None) -> np.ndarray:
        k = len(sdirs)
        e1 = np.repeat(j.u[None, :], k, axis=0)
        c = np.repeat(j.center[None, :], k, axis=0)
        core = self.opt.core_size if core is None else core
        layer = self.opt.layer_thickness if layer is None else layer
        return cs.section_vertices(self.template, c, e1, sdirs, R, core, layer)

    def _layer_and_core(self, key):
        """Boundary-layer thickness and core size of a section (after local fixes)."""
        layer = min(0.5, self.opt.layer_thickness * self.layer_scale.get(key, 1.0))
        core = self.opt.core_size * self.core_scale.get(key, 1.0)
        # keep the core corner inside the ring with some room
        core = min(core, 0.8 * (1.0 - layer) / np.sqrt(2.0))
        return layer, core

    def choose_rotations(self, nodes=None):
        opt = self.opt
        ncand = max(1, int(opt.rotation_candidates))
        for c, j in self.junctions.items():
            if nodes is not None and c not in nodes:
                continue
            m = len(j.neighbors)
            spine = self.spine_rays(j)
            if np.any(~np.isfinite(spine)):
                raise MeshingError(f"junction at skeleton node {c}: no wall found along its reference line (is the node inside the vessel?)")
            # candidate offsets per separator, symmetric about the bisector
            frac = np.linspace(-1.0, 1.0, ncand) if ncand > 1 else np.zeros(1)
            psi = (opt.rotation_range * 0.5 * j.gap)[:, None] * frac[None, :]  # (m, ncand)
            ang = j.separator[:, None] + psi
            sdirs = np.cos(ang)[..., None] * j.p + np.sin(ang)[..., None] * j.q  # (m, ncand, 3)
            R = self._half_rays(j, sdirs.reshape(-1, 3))
            if np.any(~np.isfinite(R)):
                bad = ~np.all(np.isfinite(R), axis=1).reshape(m, ncand)
                if bad.all(axis=1).any():
                    raise MeshingError(f"junction at skeleton node {c}: a half cross-section finds no wall within reach")
            V = self._half_vertices(j, sdirs.reshape(-1, 3), np.nan_to_num(R, nan=1e6)).reshape(m, ncand, -1, 3)
            upper = self.template.upper
            rel = V[:, :, upper] - j.center
            mean_dist = np.linalg.norm(rel, axis=3).mean(axis=2)  # (m, ncand)
            # reach of each half-section along its two neighbours' directions
            dirs = j.dirs
            room = self._neighbour_room(j)
            rad = self.sk.radii[j.neighbors]
            # reach along the branches from the node (the half-sections' line may be off it)
            reach_a = (rel @ dirs.T) + ((j.center - self.pos[c]) @ dirs.T)  # (m, ncand, nv_up, m)
            over = np.zeros((m, ncand))
            for h in range(m):
                for nbh in (h, (h + 1) % m):
                    r = reach_a[h, :, :, nbh].max(axis=1)
                    over[h] += np.maximum(0.0, r + opt.junction_margin * rad[nbh] - room[nbh]) / rad[nbh]
            j.reach_table = reach_a.max(axis=2)  # (m, ncand, m)
            j.cand_psi = psi
            j.cand_cost = mean_dist / j.radius + 10.0 * over + 0.05 * frac[None, :] ** 2
            j.cand_cost[~np.isfinite(R).all(axis=1).reshape(m, ncand)] = np.inf
            if opt.junction_rotation == "bisector":
                pick = np.full(m, ncand // 2)
            else:
                pick = np.argmin(j.cand_cost, axis=1)
            j.pick = pick
            j.psi = psi[np.arange(m), pick]

    # -- 5. sections ----------------------------------------------------------------
    def _node_normals(self, br: _Branch) -> np.ndarray:
        """Section normal at each node of a branch (pointing along the branch)."""
        sk = self.sk
        P = self.pos[br.nodes]
        K = len(P) - 1
        seg = cs.unit(np.diff(P, axis=0))
        n = np.empty((K + 1, 3))
        n[0], n[K] = seg[0], seg[-1]
        if K >= 2:
            n[1:K] = cs.bisector_normals(P[:-2], P[1:-1], P[2:], sk.radii[br.nodes[1:-1]], self.opt.plane_bias)
        if br.kinds[0] == CYCLE:
            n[0] = n[K] = cs.bisector_normals(P[-2:-1], P[:1], P[1:2], sk.radii[br.nodes[:1]], self.opt.plane_bias)[0]
        for side, k in ((0, 0), (1, K)):
            if br.kinds[side] == OPEN and br.caps[side] and self.caps:
                cap = self.cap_of[int(br.nodes[k])]
                out = cs.unit(np.asarray(cap.normal, float))
                n[k] = -out if side == 0 else out
        return n

    def _clearance(self):
        """Arc length from each junction along each of its branches where sections are clear."""
        opt, sk, t = self.opt, self.sk, self.template
        jobs = []
        for c, j in self.junctions.items():
            for h, (bi, side) in enumerate(j.ends):
                br = self.branches[bi]
                rb = float(np.median(sk.radii[br.nodes]))
                L = br.arc[-1]
                limit = min((0.45 if br.kinds[1 - side] == JUNCTION else 0.8) * L, 3.0 * j.radius + 2.0 * rb)
                s = 0.25 * rb * np.arange(1, int(limit / (0.25 * rb)) + 1)
                s = s[s < limit]
                if len(s) == 0:
                    continue
                jobs.append((c, h, bi, side, s))
        if not jobs:
            return {}
        centers, normals, radii, owner = [], [], [], []
        for n_job, (c, h, bi, side, s) in enumerate(jobs):
            br = self.branches[bi]
            arc = br.arc if side == 0 else br.arc[-1] - br.arc[::-1]
            nodes = br.nodes if side == 0 else br.nodes[::-1]
            P = self.pos[nodes]
            N = self._node_normals(br)
            N = N if side == 0 else -N[::-1]
            pos, nrm = polyline_at(P, arc, s, N)
            _, rad = polyline_at(P, arc, s, sk.radii[nodes])
            centers.append(pos)
            normals.append(cs.unit(nrm))
            radii.append(rad)
            owner.append(np.full(len(s), n_job))
        centers, normals, radii, owner = map(np.concatenate, (centers, normals, radii, owner))
        e1 = cs.any_perpendicular(normals)
        e2 = np.cross(normals, e1)
        ang = t.loop_angle
        dirs = cs.ray_directions(e1, e2, ang)
        R = self.cast(np.repeat(centers, len(ang), axis=0), dirs.reshape(-1, 3), np.repeat(radii, len(ang)), reach=4.0 * opt.clear_ray_factor)
        R = R.reshape(len(centers), len(ang))
        clean = np.all(np.isfinite(R) & (R <= opt.clear_ray_factor * radii[:, None]), axis=1)
        out = {}
        for n_job, (c, h, bi, side, s) in enumerate(jobs):
            ok = clean[owner == n_job]
            # first candidate from which on every later one is clean
            bad = np.flatnonzero(~ok)
            first = 0 if len(bad) == 0 else bad[-1] + 1
            out[(bi, side)] = 0.0 if first == 0 else (s[first] if first < len(s) else s[-1])
        return out

    def place_sections(self):
        """Section positions along each branch: clear of junctions, otherwise at the nodes."""
        clear = self._clearance()
        self.clear = clear
        for br in self.branches:
            br.s = br.arc.copy()
        self.retreat = self._dome_retreat()
        self._apply_clearance()

    def _dome_retreat(self) -> dict:
        """How far each closed end's section moves back from its endpoint along the branch.

        The dome beyond a closed end's section is closed by a cap of blocks
        (:meth:`_dome_cap`) that carries the boundary layer round it; the cap needs a dome
        about as high as the section is wide, or its blocks are flattened against the
        section. Endpoints often lie closer to the dome than that (a skeleton ends inside
        the sac, where the inscribed sphere touches the dome): the section goes back to the
        first position (in steps of a tenth of the endpoint's radius, up to
        ``dome_max_retreat`` radii and half the branch) where the wall ahead along the axis
        is at least ``dome_depth`` times the mean distance to the wall in the section, or
        where that ratio is highest.

        Returns
        -------
        dict ``{(branch, side): arc length}``.
        """
        opt, sk, t = self.opt, self.sk, self.template
        jobs = []
        for bi, br in enumerate(self.branches):
            for side in (0, 1):
                if br.kinds[side] != CLOSED:
                    continue
                end = int(br.nodes[-1] if side == 1 else br.nodes[0])
                r_end = float(sk.radii[end])
                limit = min(opt.dome_max_retreat * r_end, 0.5 * br.arc[-1])
                back = np.arange(0.0, limit + 1e-12, 0.1 * r_end)
                jobs.append((bi, side, back))
        if not jobs:
            return {}
        centers, normals, radii, owner = [], [], [], []
        for n_job, (bi, side, back) in enumerate(jobs):
            br = self.branches[bi]
            N = self._node_normals(br)
            s = back if side == 0 else br.arc[-1] - back
            pos, nrm = polyline_at(self.pos[br.nodes], br.arc, s, N)
            _, rad = polyline_at(self.pos[br.nodes], br.arc, s, sk.radii[br.nodes])
            centers.append(pos)
            normals.append(cs.unit(nrm) * (1.0 if side == 1 else -1.0))  # outward
            radii.append(rad)
            owner.append(np.full(len(s), n_job))
        centers, normals, radii, owner = map(np.concatenate, (centers, normals, radii, owner))
        e1 = cs.any_perpendicular(normals)
        e2 = np.cross(normals, e1)
        dirs = np.concatenate([cs.ray_directions(e1, e2, t.loop_angle), normals[:, None, :]], axis=1)
        nr = dirs.shape[1]
        R = self.cast(np.repeat(centers, nr, axis=0), dirs.reshape(-1, 3), np.repeat(radii, nr)).reshape(len(centers), nr)
        ratio = R[:, -1] / np.mean(R[:, :-1], axis=1)
        ratio = np.where(np.isfinite(ratio), ratio, -np.inf)
        out = {}
        for n_job, (bi, side, back) in enumerate(jobs):
            rj = ratio[owner == n_job]
            deep = np.flatnonzero(rj >= opt.dome_depth)
            out[(bi, side)] = float(back[deep[0]] if len(deep) else back[int(np.argmax(rj))])
        return out

    def _junction_reach(self, bi: int, side: int) -> float:
        """How far the half-sections of the junction at a branch's end reach along it."""
        br = self.branches[bi]
        c = int(br.nodes[0] if side == 0 else br.nodes[-1])
        j = self.junctions[c]
        h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
        m = len(j.neighbors)
        seps = [(h - 1) % m, h]
        return float(max(j.reach_table[sp, j.pick[sp], h] for sp in seps))

    def _apply_clearance(self):
        opt, sk = self.opt, self.sk
        self.infeasible = []
        if not hasattr(self, "crowded"):
            self.crowded = set()  # branches between two junctions that ever lacked room
        for bi, br in enumerate(self.branches):
            if br.kinds == [JUNCTION, JUNCTION] and br.nodes[0] != br.nodes[-1] and self._slack(bi) < 0:
                self.crowded.add(bi)
            lo, hi = 0.0, br.arc[-1]
            rb = float(np.median(sk.radii[br.nodes]))
            for side in (0, 1):
                if br.kinds[side] != JUNCTION:
                    continue
                need = max(self.clear.get((bi, side), 0.0), self._junction_reach(bi, side) + (opt.junction_margin + br.margin[side]) * rb)
                if side == 0:
                    lo = need
                else:
                    hi = br.arc[-1] - need
            # closed ends' sections stand back from the dome (:meth:`_dome_retreat`)
            ends = br.arc.copy()
            ends[0] += self.retreat.get((bi, 0), 0.0)
            ends[-1] -= self.retreat.get((bi, 1), 0.0)
            if br.kinds[1] in (OPEN, CLOSED):
                hi = ends[-1] - 0.3 * rb
            if br.kinds[0] in (OPEN, CLOSED):
                lo = max(lo, ends[0] + 0.3 * rb)
            br.s, ok = redistribute_sections(ends, lo, hi)
            if not ok:
                self.infeasible.append(bi)

    # -- 6. frames and ray casting ------------------------------------------------------
    def section_geometry(self):
        """Centres, normals, frames and radii of every section (flat arrays) and the
        per-branch index of its sections."""
        sk, t = self.sk, self.template
        sym = t.symmetry_angle
        rows = []  # per branch: (centers, normals, radii) at sections
        B = len(self.branches)
        Kmax = max(len(br.nodes) for br in self.branches)
        X = np.zeros((B, Kmax, 3))
        T = np.zeros((B, Kmax, 3))
        first = np.zeros((B, 3))
        counts = np.zeros(B, np.int64)
        for bi, br in enumerate(self.branches):
            P = self.pos[br.nodes].copy()
            N = self._node_normals(br)
            pos, nrm = polyline_at(P, br.arc, br.s, N)
            # positions exactly at unmoved nodes, and end sections on their caps
            for side, k in ((0, 0), (1, len(P) - 1)):
                if br.kinds[side] == OPEN and br.caps[side] and self.caps:
                    pos[k] = np.asarray(self.cap_of[int(br.nodes[k])].center, float)
            if br.straighten is not None and br.straighten.any():
                chord = cs.unit(np.gradient(pos, axis=0))
                nrm = (1 - br.straighten[:, None]) * nrm + br.straighten[:, None] * chord
            nrm = cs.unit(nrm)
            _, rad = polyline_at(P, br.arc, br.s, sk.radii[br.nodes])
            K = len(P)
            X[bi, :K], T[bi, :K], counts[bi] = pos, nrm, K
            if br.kinds[0] == JUNCTION:
                T[bi, 0] = cs.unit(pos[1] - pos[0])
                first[bi] = self.junctions[int(br.nodes[0])].u
            else:
                first[bi] = cs.any_perpendicular(nrm[:1])[0]
            if br.kinds[1] == JUNCTION:
                T[bi, K - 1] = cs.unit(pos[-1] - pos[-2])
            rows.append(rad)
        E1 = cs.transport_frames(X, T, first, counts)
        twist_total = np.zeros(B)
        self.end_turn = {}
        for bi, br in enumerate(self.branches):
            K = counts[bi]
            if br.kinds[1] == JUNCTION or br.kinds[1] == CYCLE:
                target = self.junctions[int(br.nodes[-1])].u if br.kinds[1] == JUNCTION else E1[bi, 0]
                phi, _ = cs.residual_twist(E1[bi, K - 1][None], target[None], T[bi, K - 1][None], sym)
                twist_total[bi] = phi[0]
                s = br.s - br.s[0]
                frac = s / max(s[-1], 1e-300)
                E1[bi, :K] = cs.rotate_about(E1[bi, :K], T[bi, :K], twist_total[bi] * frac)
        self.X, self.T, self.E1, self.counts, self.R_node = X, T, E1, counts, rows
        self.twist_total = twist_total
        # twist between consecutive sections (after spreading) for the report
        tw = []
        for bi, br in enumerate(self.branches):
            K = counts[bi]
            if K >= 2:
                s = br.s - br.s[0]
                tw.append(np.abs(twist_total[bi]) * np.diff(s) / max(s[-1], 1e-300))
        self.max_twist = float(np.degrees(np.concatenate(tw).max())) if tw else 0.0

    def cast(self, origins, directions, scale, reach: float = 12.0) -> np.ndarray:
        return cs.cast_rays(self.sdf, origins, directions, scale, reach=reach, intersect_lines=self.intersect_lines)

    def regular_sections(self):
        """Vertices of every regular (non-junction) section."""
        t = self.template
        idx = []  # (branch, k)
        for bi, br in enumerate(self.branches):
            K = len(br.nodes)
            for k in range(K):
                side = 0 if k == 0 else (1 if k == K - 1 else -1)
                if side >= 0 and br.kinds[side] == JUNCTION:
                    continue
                if k == K - 1 and br.kinds[1] == CYCLE:
                    continue  # the same section as k = 0
                idx.append((bi, k))
        bi_arr = np.array([i for i, _ in idx])
        k_arr = np.array([k for _, k in idx])
        C = self.X[bi_arr, k_arr]
        Nn = self.T[bi_arr, k_arr]
        E1 = cs.unit(cs.reject(self.E1[bi_arr, k_arr], Nn))
        E2 = np.cross(Nn, E1)
        rad = np.array([self.R_node[b][k] for b, k in idx])
        # which way is out at end sections
        outward = np.zeros(len(idx))
        for n, (b, k) in enumerate(idx):
            br = self.branches[b]
            if k == 0 and br.kinds[0] in (OPEN, CLOSED):
                outward[n] = -1.0
            elif k == len(br.nodes) - 1 and br.kinds[1] in (OPEN, CLOSED):
                outward[n] = 1.0
        # flat caps give the signed distance no sign on their plane: cast from just inside
        is_open = np.array([(k == 0 and self.branches[b].kinds[0] == OPEN) or
                            (k == len(self.branches[b].nodes) - 1 and self.branches[b].kinds[1] == OPEN) for b, k in idx])
        shift = (0.05 * rad * outward * is_open)[:, None] * Nn
        origin = C - shift
        ang = t.ray_angles
        dirs = cs.ray_directions(E1, E2, ang)
        R = self.cast(np.repeat(origin, len(ang), axis=0), dirs.reshape(-1, 3), np.repeat(rad, len(ang))).reshape(len(idx), -1)
        if np.any(~np.isfinite(R)):
            n = int(np.flatnonzero(~np.all(np.isfinite(R), axis=1))[0])
            b, k = idx[n]
            node = int(self.branches[b].nodes[k])
            raise MeshingError(f"cross-section at skeleton node {node} finds no wall within reach (is the node inside the vessel?)")
        lc = np.array([self._layer_and_core((b, k)) for b, k in idx]).reshape(-1, 2)
        V = cs.section_vertices(t, C, E1, E2, R, lc[:, 1], lc[:, 0])
        on_surface = np.zeros(V.shape[:2], bool)
        on_surface[:, t.kind == cs.VERTEX_OUTER] = True
        # closed ends: the section stays flat; the dome beyond it is closed by a cap of blocks
        self.domes = []
        for n, (b, k) in enumerate(idx):
            br = self.branches[b]
            if (k == 0 and br.kinds[0] == CLOSED) or (k == len(br.nodes) - 1 and br.kinds[1] == CLOSED):
                self.domes.append(self._dome_cap(n, int(br.nodes[k]), C[n], V[n], Nn[n] * outward[n], rad[n], lc[n, 0], lc[n, 1]))
        return idx, V, on_surface, R

    def _dome_cap(self, n: int, node: int, c: np.ndarray, V: np.ndarray, d: np.ndarray, rad: float, layer: float, core: float) -> dict:
        """Corners of the cap of blocks that closes the dome beyond a closed end's flat section.

        A closed end's boundary layer has to turn round the dome with the wall: blocks with
        a side face and an end face both on the smooth dome would meet it at a straight
        angle and fold their elements there. The cap is the upper half of a ball's O-grid
        (a cube projected onto the sphere) standing on the section: the section's core
        square is lifted along the outward axis ``d`` by ``core`` times the wall distance
        ahead (``lifted``), and rays from the section centre ``c`` through the lifted
        corners find the dome (``wall``) and the boundary layer's inner surface at
        ``1 - layer`` of the way (``inner``), as rays in the section plane place its ring
        and outer corners. The assembly joins the core square to ``lifted`` (the cap's core),
        ``lifted`` to ``inner`` and the section's ring quads to both (the cap's ring), and
        ``inner`` to ``wall`` and the section's boundary-layer quads to both (the boundary
        layer over the dome, continuing the side wall's).

        Returns
        -------
        dict with ``section`` (index of the end section), ``core`` (template core vertices)
        and their ``lifted``, ``inner`` and ``wall`` positions ((len(core), 3) each).
        """
        t = self.template
        core_v = np.flatnonzero(t.kind == cs.VERTEX_CORE)
        ahead = self.cast(c[None], d[None], np.array([rad]))[0]
        if not np.isfinite(ahead):
            raise MeshingError(f"closed end at skeleton node {node}: no wall found ahead of its cross-section")
        lifted = V[core_v] + core * ahead * d
        dirs = cs.unit(lifted - c)
        R = self.cast(np.repeat(c[None], len(dirs), 0), dirs, np.full(len(dirs), rad))
        if np.any(~np.isfinite(R)):
            raise MeshingError(f"closed end at skeleton node {node}: no wall found round the dome beyond its cross-section")
        return {"section": n, "core": core_v, "lifted": lifted,
                "inner": c + ((1.0 - layer) * R)[:, None] * dirs, "wall": c + R[:, None] * dirs}

    # -- 7. assembly ------------------------------------------------------------------
    def assemble(self) -> BlockStructure:
        t, sk = self.template, self.sk
        self.section_geometry()
        nv_t = t.n_vertices
        verts, on_surf = [], []
        n_vert = 0
        # regular sections
        idx, V, S, _ = self.regular_sections()
        sec_ids = {}
        for n, key in enumerate(idx):
            sec_ids[key] = n_vert + np.arange(nv_t)
            n_vert += nv_t
        verts.append(V.reshape(-1, 3))
        on_surf.append(S.reshape(-1))
        # junctions: spine + upper halves
        upper, spine = t.upper, t.spine
        for c, j in self.junctions.items():
            m = len(j.neighbors)
            sdirs = j.separator_dir(np.arange(m))
            R = self._half_rays(j, sdirs)
            layer, core = self._layer_and_core(("J", c))
            HV = self._half_vertices(j, sdirs, R, core, layer)
            j.spine_ids = np.full(nv_t, -1, np.int64)
            j.spine_ids[spine] = n_vert + np.arange(spine.sum())
            verts.append(HV[0, spine])
            on_surf.append(t.kind[spine] == cs.VERTEX_OUTER)
            n_vert += int(spine.sum())
            only_up = upper & ~spine
            j.half_ids = np.full((m, nv_t), -1, np.int64)
            for h in range(m):
                j.half_ids[h, spine] = j.spine_ids[spine]
                j.half_ids[h, only_up] = n_vert + np.arange(only_up.sum())
                n_vert += int(only_up.sum())
                verts.append(HV[h, only_up])
                on_surf.append(t.kind[only_up] == cs.VERTEX_OUTER)
            j.half_vertices = HV
        # dome caps: the lifted core square, and its rays' points on the layer and the dome
        for dome in self.domes:
            cv = dome["core"]
            for name, onwall in (("lifted", False), ("inner", False), ("wall", True)):
                dome[name + "_ids"] = np.full(nv_t, -1, np.int64)
                dome[name + "_ids"][cv] = n_vert + np.arange(len(cv))
                n_vert += len(cv)
                verts.append(dome[name])
                on_surf.append(np.full(len(cv), onwall))
        vertices = np.vstack(verts)
        on_surface = np.concatenate(on_surf)

        hexes, fb, ak, radius, bnode, bseg, blayer, btags, where = [], [], [], [], [], [], [], [], []
        q = t.quads
        nq = len(q)
        for bi, br in enumerate(self.branches):
            K = len(br.nodes)
            ids = [None] * K
            for k in range(K):
                side = 0 if k == 0 else (1 if k == K - 1 else -1)
                if side >= 0 and br.kinds[side] == JUNCTION:
                    ids[k] = self._folded_ids(bi, side)
                elif k == K - 1 and br.kinds[1] == CYCLE:
                    ids[k] = self._cycle_close_ids(bi, sec_ids[(bi, 0)])
                else:
                    ids[k] = sec_ids[(bi, k)]
            for k in range(K - 1):
                a, b = ids[k][q], ids[k + 1][q]
                hexes.append(np.hstack([a, b]))
                f = np.full((nq, 6), FACE_INTERIOR, np.int64)
                f[t.quad_wall, 1] = FACE_WALL
                # open ends lie on their caps; closed ends are shared with their dome's cap blocks
                if k == 0 and br.kinds[0] == OPEN:
                    f[:, 4] = br.caps[0]
                if k == K - 2 and br.kinds[1] == OPEN:
                    f[:, 5] = br.caps[1]
                fb.append(f)
                ak.append(np.c_[t.quad_axes, np.full(nq, AXIS_ALONG)])
                n0, n1 = int(br.nodes[k]), int(br.nodes[k + 1])
                e = int(br.edges[k])
                radius.append(np.full(nq, 0.5 * (self.R_node[bi][k] + self.R_node[bi][k + 1])))
                bnode.append(np.full(nq, n0))
                bseg.append(np.full(nq, e))
                blayer.append(t.quad_layer)
                tags = tuple(sorted(set(sk.node_tags[n0]) | set(sk.node_tags[n1]) | set(sk.edge_tags[e])))
                btags.extend([tags] * nq)
                where.append(np.c_[np.full(nq, bi), np.full(nq, k)])
        loop_of = np.full(nv_t, -1, np.int64)  # ring and outer vertices -> the loop vertex on their ray
        loop_of[t.ring] = t.loop
        loop_of[t.outer] = t.loop
        for dome in self.domes:
            bi, k = idx[dome["section"]]
            br = self.branches[bi]
            kseg = 0 if k == 0 else k - 1
            E, L, I, W = sec_ids[(bi, k)], dome["lifted_ids"], dome["inner_ids"], dome["wall_ids"]
            cq, rq, bq = (q[t.quad_layer == lay] for lay in (LAYER_CORE, LAYER_RING, LAYER_BOUNDARY))
            ax_c, ax_r, ax_b = (t.quad_axes[t.quad_layer == lay] for lay in (LAYER_CORE, LAYER_RING, LAYER_BOUNDARY))
            lb = loop_of[bq]  # ring quads start and end on loop vertices already
            blocks_ = [
                # the cap's core: the section's core square lifted along the axis
                (np.hstack([E[cq], L[cq]]), np.c_[ax_c, np.full(len(cq), AXIS_ALONG)], LAYER_CORE, False),
                # the cap's ring over the core, and round it from the section's ring quads
                (np.hstack([L[cq], I[cq]]), np.c_[ax_c, np.full(len(cq), AXIS_RING)], LAYER_RING, False),
                (np.hstack([E[rq], np.stack([L[rq[:, 0]], I[rq[:, 0]], I[rq[:, 3]], L[rq[:, 3]]], 1)]), np.c_[ax_r, np.full(len(rq), AXIS_ALONG)], LAYER_RING, False),
                # the boundary layer over the dome (across its first axis, wall face 1 as in the
                # ring's layer) and round it from the section's boundary-layer quads
                (np.stack([I[cq[:, 0]], W[cq[:, 0]], W[cq[:, 1]], I[cq[:, 1]], I[cq[:, 3]], W[cq[:, 3]], W[cq[:, 2]], I[cq[:, 2]]], 1),
                 np.c_[np.full(len(cq), AXIS_LAYER), ax_c], LAYER_BOUNDARY, True),
                (np.hstack([E[bq], np.stack([I[lb[:, 0]], W[lb[:, 0]], W[lb[:, 3]], I[lb[:, 3]]], 1)]), np.c_[ax_b, np.full(len(bq), AXIS_ALONG)], LAYER_BOUNDARY, True),
            ]
            n0, n1 = int(br.nodes[kseg]), int(br.nodes[kseg + 1])
            e = int(br.edges[kseg])
            tags = tuple(sorted(set(sk.node_tags[n0]) | set(sk.node_tags[n1]) | set(sk.edge_tags[e])))
            for hx, axes, lay, on_wall in blocks_:
                m = len(hx)
                hexes.append(hx)
                f = np.full((m, 6), FACE_INTERIOR, np.int64)
                if on_wall:
                    f[:, 1] = FACE_WALL
                fb.append(f)
                ak.append(axes)
                radius.append(np.full(m, self.R_node[bi][k]))
                bnode.append(np.full(m, n0))
                bseg.append(np.full(m, e))
                blayer.append(np.full(m, lay))
                btags.extend([tags] * m)
                where.append(np.c_[np.full(m, bi), np.full(m, kseg)])
        hexes = np.vstack(hexes)
        fb = np.vstack(fb)
        ak = np.vstack(ak)
        # blocks whose every corner is negative are only mirrored: flip them along k
        J = BlockStructure(vertices, hexes, on_surface, fb, ak, np.concatenate(radius), np.concatenate(bnode),
                           np.concatenate(bseg), np.concatenate(blayer), btags).corner_jacobians()
        flip = np.all(J < 0, axis=1)
        if flip.any():
            hexes[flip] = hexes[flip][:, [4, 5, 6, 7, 0, 1, 2, 3]]
            fb[flip] = fb[flip][:, [0, 1, 2, 3, 5, 4]]
        self.block_where = np.vstack(where)
        self.block_layers = np.concatenate(blayer)
        blocks = BlockStructure(
            vertices=vertices,
            hexes=hexes,
            vertex_on_surface=on_surface,
            face_boundary=fb,
            axis_kind=ak,
            block_radius=np.concatenate(radius),
            block_node=np.concatenate(bnode),
            block_segment=np.concatenate(bseg),
            block_layer=np.concatenate(blayer),
            block_tags=btags,
            boundary_names=dict(self.boundary_names),
        )
        self.info = {
            "blocks_around": t.n_around,
            "core": [t.a, t.b],
            "max_twist_deg": round(self.max_twist, 3),
            "branches": len(self.branches),
            "junctions": {int(c): {"neighbors": j.neighbors.tolist(), "axis": j.u.round(6).tolist(),
                                   "rotation_deg": np.degrees(j.psi).round(2).tolist()} for c, j in self.junctions.items()},
            "flipped_blocks": int(flip.sum()),
            "dome_caps": len(self.domes),
            "dome_retreat": {int(self.branches[bi].nodes[-1 if side else 0]): round(v, 4) for (bi, side), v in self.retreat.items()},
            "skeleton": self.sk,
        }
        return blocks

    def _folded_ids(self, bi: int, side: int) -> np.ndarray:
        """Global vertex id of each template vertex of a branch's end section at a junction."""
        t = self.template
        br = self.branches[bi]
        K = len(br.nodes)
        k = 0 if side == 0 else K - 1
        c = int(br.nodes[k])
        j = self.junctions[c]
        h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
        m = len(j.neighbors)
        n = self.T[bi, k]
        e1 = self.E1[bi, k]
        E1 = cs.unit(cs.reject(j.u[None], n[None]))[0]
        E2 = np.cross(n, E1)
        rho = cs.signed_angle(E1[None], e1[None], n[None])[0]
        perm = min(t.symmetries, key=lambda s: abs(np.angle(np.exp(1j * (s[0] - rho)))))[1]
        canon = perm  # template vertex -> canonical vertex
        seps = [(h - 1) % m, h]
        s_dirs = j.separator_dir(np.array(seps))
        up_first = (s_dirs[0] @ E2) >= (s_dirs[1] @ E2)
        h_up, h_low = (seps[0], seps[1]) if up_first else (seps[1], seps[0])
        y = t.xy[canon, 1]
        ids = np.where(y > 1e-12, j.half_ids[h_up, canon], j.half_ids[h_low, t.mirror[canon]])
        ids = np.where(np.abs(y) <= 1e-12, j.spine_ids[canon], ids)
        return ids

    def _cycle_close_ids(self, bi: int, first_ids: np.ndarray) -> np.ndarray:
        """Ids of a cycle's closing section: its first section seen in the transported frame."""
        t = self.template
        K = self.counts[bi]
        n = self.T[bi, K - 1]
        rho = cs.signed_angle(cs.reject(self.E1[bi, 0][None], n[None]), self.E1[bi, K - 1][None], n[None])[0]
        perm = min(t.symmetries, key=lambda s: abs(np.angle(np.exp(1j * (s[0] - rho)))))[1]
        return first_ids[perm]

    # -- 8. validity -----------------------------------------------------------------------
    def relieve_wall_folds(self, blocks: BlockStructure) -> BlockStructure:
        """Re-place the first cross-sections and half-planes at junctions whose boundary
        layer would fold in the transfinite fill.

        At a junction crotch the half cross-section meets the wall obliquely: a boundary-layer
        block from it to a branch section that stands close is short on the crotch side and
        long on the other, and projecting its wall face folds it. Junctions with such blocks
        (:func:`projected_wall_quality` at most ``wall_quality``) get, per branch end, the
        extra margin of ``wall_margins`` whose blocks fill best, and where they still fold,
        the half-plane rotations whose blocks fill best, then margins again. Blocks are
        judged by filling them (:func:`fill_quality`, at the default and a finer
        resolution, without untangling); the new placement is kept only when the
        junction's blocks fill better at one resolution and no worse at any, and every
        block stays valid."""
        opt = self.opt
        quality = projected_wall_quality(blocks, self.project)
        ends = self._junction_ends(np.flatnonzero(quality <= opt.wall_quality))
        if not ends:
            return blocks
        nodes = sorted({int(self.branches[bi].nodes[-side]) for bi, side in ends})
        near = self._junction_blocks(nodes)
        before = self._checked_score(blocks, near)
        saved = ([br.margin.copy() for br in self.branches],
                 {c: (j.pick.copy(), j.psi.copy()) for c, j in self.junctions.items()})
        trial = self._margins_for_wall(ends)
        after = self._checked_score(trial, near)
        if np.any(after < 0):
            # still folded: turn the half-planes too, then place the first sections again
            self._rotate_for_wall(ends)
            trial = self._margins_for_wall(ends)
            after = self._checked_score(trial, near)
        if not (np.all(after >= before - 1e-9) and np.any(after > before + 1e-9)):
            # the junction's blocks fill no better at some resolution: back to where they were
            for br, m in zip(self.branches, saved[0]):
                br.margin = m
            for c, (pick, psi) in saved[1].items():
                self.junctions[c].pick, self.junctions[c].psi = pick, psi
            self._apply_clearance()
            return self.assemble()
        self.fixes.append(f"re-placed the half cross-sections and first cross-sections at junction node(s) {nodes} "
                          f"where the boundary layer would fold (fill scores {np.round(before, 3).tolist()} -> {np.round(after, 3).tolist()})")
        return trial

    def _checked_score(self, blocks: BlockStructure, near: np.ndarray) -> np.ndarray:
        """:func:`fill_score` of the blocks ``near`` per fill resolution; -inf when any block
        is invalid."""
        if blocks.corner_jacobians().min() <= 0:
            return np.full(len(FILL_CHECKS), -np.inf)
        q = fill_quality(blocks, near, self.project, self.sdf, self.intersect_lines, per_resolution=True)
        return np.array([fill_score(row) for row in q])

    def _margins_for_wall(self, ends: list) -> BlockStructure:
        """Give each junction end of ``ends`` the extra margin of ``wall_margins`` whose
        first-segment blocks fill best (the least reaching ``good_wall_quality``); the ends
        are independent, so one assembly per margin scores them all. Returns the assembly."""
        opt = self.opt
        base = {e: float(self.branches[e[0]].margin[e[1]]) for e in ends}
        steps = np.asarray(opt.wall_margins, float)
        score = np.full((len(ends), len(steps)), -np.inf)
        for n, add in enumerate(steps):
            for bi, side in ends:
                self.branches[bi].margin[side] = base[(bi, side)] + add
            self._apply_clearance()
            trial = self.assemble()
            J = trial.corner_jacobians().min(axis=1)
            mine = [self._end_blocks(bi, side) for bi, side in ends]
            sel = np.unique(np.concatenate(mine))
            q = np.ones(trial.n_blocks)
            q[sel] = self._fill_quality(trial, sel)
            for e, (bi, side) in enumerate(ends):
                if J[self.block_where[:, 0] == bi].min() > 0:
                    score[e, n] = fill_score(q[mine[e]])
        pick = np.argmax(np.minimum(score, opt.good_wall_quality), axis=1)
        for e, (bi, side) in enumerate(ends):
            self.branches[bi].margin[side] = base[(bi, side)] + (steps[pick[e]] if np.isfinite(score[e, pick[e]]) else 0.0)
        self._apply_clearance()
        return self.assemble()

    def _junction_blocks(self, nodes) -> np.ndarray:
        """Blocks of the first segment of every branch end at the junctions ``nodes``."""
        return np.unique(np.concatenate([self._end_blocks(bi, side) for c in nodes for bi, side in self.junctions[c].ends]))

    def _rotate_for_wall(self, ends: list) -> None:
        """Re-rotate the half-planes next to the junction ends ``ends`` (``(branch, side)``)
        to the candidate whose boundary-layer blocks fold least on the wall.

        A half-plane's blocks are those with a vertex of its half-section off the spine;
        all touched half-planes try their candidates in step (one assembly per candidate),
        each keeps its own best (ties: the current one), and the blocks must stay valid."""
        opt = self.opt
        seps = set()
        for bi, side in ends:
            c = int(self.branches[bi].nodes[0 if side == 0 else -1])
            j = self.junctions[c]
            h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
            seps |= {(c, (h - 1) % len(j.neighbors)), (c, h)}
        seps = sorted(seps)
        ncand = max(len(self.junctions[c].cand_psi[sp]) for c, sp in seps)
        current = {(c, sp): int(self.junctions[c].pick[sp]) for c, sp in seps}
        score = np.full((len(seps), ncand), -np.inf)
        for n in range(ncand):
            for c, sp in seps:
                j = self.junctions[c]
                k = n if np.isfinite(j.cand_cost[sp, n]) else current[(c, sp)]
                j.pick[sp], j.psi[sp] = k, j.cand_psi[sp, k]
            self._apply_clearance()
            trial = self.assemble()
            J = trial.corner_jacobians().min(axis=1)
            near = np.unique(np.concatenate([self._end_blocks(bi, side) for c in {c for c, _ in seps} for bi, side in self.junctions[c].ends]))
            q = np.ones(trial.n_blocks)
            q[near] = self._fill_quality(trial, near)
            for e, (c, sp) in enumerate(seps):
                j = self.junctions[c]
                if not np.isfinite(j.cand_cost[sp, n]):
                    continue
                own = j.half_ids[sp][j.spine_ids < 0]
                mine = np.flatnonzero(np.isin(trial.hexes, own[own >= 0]).any(axis=1))
                branches = np.unique(self.block_where[mine, 0])
                if J[np.isin(self.block_where[:, 0], branches)].min() > 0:
                    score[e, n] = fill_score(q[mine])
        for e, (c, sp) in enumerate(seps):
            j = self.junctions[c]
            capped = np.minimum(score[e], opt.good_wall_quality)
            k = current[(c, sp)]
            if np.isfinite(capped.max()) and capped.max() > capped[k] + 1e-3:
                k = int(np.argmax(capped))
            j.pick[sp], j.psi[sp] = k, j.cand_psi[sp, k]
        self._apply_clearance()

    def _fill_quality(self, blocks: BlockStructure, subset: np.ndarray) -> np.ndarray:
        """:func:`fill_quality` of ``subset`` on this builder's wall."""
        return fill_quality(blocks, subset, self.project, self.sdf, self.intersect_lines)

    def _junction_ends(self, blocks_: np.ndarray) -> list:
        """The (branch, side) junction ends whose first segment holds any of ``blocks_``."""
        out = set()
        for bi, k in np.unique(self.block_where[blocks_], axis=0).tolist():
            br = self.branches[bi]
            K = len(br.nodes)
            if K <= 2:
                continue
            for side, at in ((0, k == 0), (1, k == K - 2)):
                if at and br.kinds[side] == JUNCTION:
                    out.add((bi, side))
        return sorted(out)

    def _end_blocks(self, bi: int, side: int) -> np.ndarray:
        """Blocks of the segment next to a branch's end ``side``."""
        K = len(self.branches[bi].nodes)
        k = 0 if side == 0 else K - 2
        return np.flatnonzero((self.block_where[:, 0] == bi) & (self.block_where[:, 1] == k))

    def thicken_layers(self, blocks: BlockStructure) -> BlockStructure:
        """Thicken the boundary layer at sections whose boundary-layer blocks would fold when
        their wall faces are projected onto the wall (:func:`projected_wall_quality`), as
        long as every block stays valid; what is left is reported in ``info``."""
        opt = self.opt
        quality = projected_wall_quality(blocks, self.project)
        thickened = set()
        for _ in range(4):
            bad = np.flatnonzero(quality <= opt.wall_quality)
            if len(bad) == 0:
                break
            keys = {self._section_key(bi, kk) for bi, k in self.block_where[bad].tolist() for kk in (k, k + 1)}
            keys = {key for key in keys if opt.layer_thickness * self.layer_scale.get(key, 1.0) < 0.5 - 1e-9}
            if not keys:
                break
            old = dict(self.layer_scale)
            for key in keys:
                self.layer_scale[key] = self.layer_scale.get(key, 1.0) * 1.25
            trial = self.assemble()
            if trial.corner_jacobians().min() <= 0:
                self.layer_scale = old
                break
            thickened |= keys
            blocks, quality = trial, projected_wall_quality(trial, self.project)
        if thickened:
            self.fixes.append(f"thickened the boundary layer at {len(thickened)} cross-section(s) where projecting the wall would fold it")
            blocks.info.update(self.info)
        return blocks

    def report_wall_folds(self, blocks: BlockStructure) -> None:
        """Record (and warn about) boundary-layer blocks that may still fold on the wall."""
        quality = projected_wall_quality(blocks, self.project)
        self.info["min_projected_wall_quality"] = round(float(quality.min()), 4)
        self.info["blocks_folding_on_wall"] = int(np.sum(quality <= 0))
        blocks.info.update(self.info)
        blocks.info["fixes"] = list(self.fixes)
        if self.info["blocks_folding_on_wall"]:
            nodes = sorted(set(blocks.block_node[quality <= 0].tolist()))
            self.warn(f"{self.info['blocks_folding_on_wall']} boundary-layer block(s) next to skeleton node(s) {nodes[:8]} may fold when their faces are projected onto the wall")

    def fix(self, bad: np.ndarray, J: np.ndarray) -> bool:
        """Change the state so that the blocks ``bad`` may become valid; False when out of ideas.

        Per failing segment, in this order: shrink the core where only core and ring blocks
        fail; near a junction, move the branch's sections further away, then re-rotate the
        junction's half-planes; between two ordinary sections, straighten their planes
        towards the segment."""
        where = self.block_where[bad]
        layer = self._last_layers(bad)
        changed = moved = False
        for bi, k in np.unique(where, axis=0).tolist():
            br = self.branches[bi]
            K = len(br.nodes)
            sel = (where[:, 0] == bi) & (where[:, 1] == k)
            if np.all(layer[sel] != LAYER_BOUNDARY):
                shrunk = False
                for kk in (k, k + 1):
                    key = self._section_key(bi, kk)
                    sc = self.core_scale.get(key, 1.0)
                    if sc > 0.45:
                        self.core_scale[key] = sc * 0.8
                        shrunk = True
                if shrunk:
                    self.fixes.append(f"shrank the core at skeleton node {int(br.nodes[k])}")
                    changed = True
                    continue
            ends = [side for side, at in ((0, k == 0), (1, k + 1 == K - 1)) if at and br.kinds[side] == JUNCTION]
            if ends:
                for side in ends:
                    node = int(br.nodes[0 if side == 0 else -1])
                    if br.margin[side] < 2.0 and K > 2:
                        br.margin[side] += 0.5
                        self.fixes.append(f"moved the cross-sections next to junction node {node} further along its branch")
                        changed = True
                    elif self._rerotate(bi, side):
                        self.fixes.append(f"re-rotated the half-planes of junction node {node}")
                        changed = True
                    elif self.separate_junctions(bi):
                        changed = moved = True
                        break
                continue
            straightened = False
            for kk in (k, k + 1):
                if br.straighten[kk] < 0.99:
                    br.straighten[kk] = min(1.0, br.straighten[kk] + 0.34)
                    straightened = True
            if straightened:
                self.fixes.append(f"straightened the cross-sections at skeleton nodes {int(br.nodes[k])}-{int(br.nodes[k + 1])}")
                changed = True
        if moved:
            self.clear = self._clearance()
        if changed:
            self._apply_clearance()
        return changed

    def _last_layers(self, bad):
        return self.block_layers[np.asarray(bad)]

    def _section_key(self, bi: int, k: int):
        br = self.branches[bi]
        K = len(br.nodes)
        if (k == 0 and br.kinds[0] == JUNCTION) or (k == K - 1 and br.kinds[1] == JUNCTION):
            return ("J", int(br.nodes[k]))
        if k == K - 1 and br.kinds[1] == CYCLE:
            return (bi, 0)
        return (bi, k)

    def _rerotate(self, bi: int, side: int) -> bool:
        """Turn the two half-planes next to a branch so that they reach less far along it."""
        br = self.branches[bi]
        c = int(br.nodes[0] if side == 0 else br.nodes[-1])
        j = self.junctions[c]
        h = next(h for h, e in enumerate(j.ends) if e == (bi, side))
        m = len(j.neighbors)
        changed = False
        for sp in ((h - 1) % m, h):
            reach = j.reach_table[sp, :, h]
            better = np.flatnonzero(reach < reach[j.pick[sp]] - 1e-9 * j.radius)
            better = better[np.isfinite(j.cand_cost[sp, better])]
            if len(better):
                # the least costly of those reaching clearly less far
                target = reach[j.pick[sp]] - 0.25 * (reach[j.pick[sp]] - reach[better].min())
                pool = better[reach[better] <= target + 1e-12]
                pick = pool[np.argmin(j.cand_cost[sp, pool])]
                j.pick[sp] = pick
                j.psi[sp] = j.cand_psi[sp, pick]
                changed = True
        return changed

    def fail(self, blocks: BlockStructure, bad: np.ndarray):
        """Raise :class:`_Failure` for the blocks ``bad``, naming the worst one's skeleton node
        and what a changed skeleton might fix: n-furcations next to the bad blocks, and
        pairs of junctions whose half cross-sections leave the branch between them no room."""
        J = blocks.corner_jacobians()
        worst = bad[np.argmin(J[bad].min(axis=1))]
        node = int(blocks.block_node[worst])
        ends = np.unique(self.sk.edges[blocks.block_segment[bad]])
        nfurc = [int(c) for c in ends if self.sk.degrees[c] > 3]
        crowded = []
        for bi in np.unique(self.block_where[bad, 0]).tolist():
            br = self.branches[bi]
            a, b = int(br.nodes[0]), int(br.nodes[-1])
            if bi in self.crowded and (min(a, b), max(a, b)) not in crowded:
                crowded.append((min(a, b), max(a, b)))
        hint = f"; set split_nonplanar = true to split junction node(s) {nfurc} into 3-junctions" if nfurc and not self.opt.split_nonplanar else ""
        where = f" (segment {int(blocks.block_segment[worst])})"
        message = (
            f"{len(bad)} block(s) stay invalid after {len(self.fixes)} fix(es); the worst starts at skeleton node {node}{where} "
            f"with corner Jacobian {J[worst].min():.3g}"
        )
        raise _Failure(message, blocks, bad, self.sk, nfurc, crowded, hint)


def projected_wall_quality(blocks: BlockStructure, project, samples: int = 4) -> np.ndarray:
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

    Returns
    -------
    (nb,) float: the smallest scaled corner Jacobian per block (1 for blocks off the wall).
    """
    from ..blocks import HEX_FACES, scaled_corner_jacobians

    out = np.ones(blocks.n_blocks)
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    # faces 0..3 (i, j sides): the opposite face across the layer; end faces (k) are skipped
    keep = f < 4
    b, f = b[keep], f[keep]
    if len(b) == 0:
        return out
    wall = blocks.vertices[blocks.hexes[b[:, None], HEX_FACES[f]]]  # (m, 4, 3), outward order
    # the opposite face in the same corner order: reversed orientation, matched corner by corner
    match = {0: [1, 5, 6, 2], 1: [0, 3, 7, 4], 2: [3, 2, 6, 7], 3: [0, 4, 5, 1]}
    inner = blocks.vertices[blocks.hexes[b[:, None], np.array([match[int(x)] for x in f])]]
    s = np.linspace(0.0, 1.0, samples + 1)
    U, V = np.meshgrid(s, s, indexing="ij")
    w = np.stack([(1 - U) * (1 - V), U * (1 - V), U * V, (1 - U) * V], axis=-1)  # (n+1, n+1, 4)
    outer_grid = np.einsum("abc,mcd->mabd", w, wall)
    inner_grid = np.einsum("abc,mcd->mabd", w, inner)
    shape = outer_grid.shape
    outer_grid = np.asarray(project(outer_grid.reshape(-1, 3))).reshape(shape)
    o, i = outer_grid, inner_grid
    # sub-hexes: bottom = inner cell, top = projected wall cell (outward along the layer)
    H = np.stack([i[:, :-1, :-1], i[:, 1:, :-1], i[:, 1:, 1:], i[:, :-1, 1:],
                  o[:, :-1, :-1], o[:, 1:, :-1], o[:, 1:, 1:], o[:, :-1, 1:]], axis=3)
    sj = scaled_corner_jacobians(H.reshape(-1, 8, 3)).min(axis=1).reshape(len(b), -1)
    # wall corners run outward: the inner cell (bottom) faces the projected wall (top)
    sj = sj.min(axis=1)
    np.minimum.at(out, b, sj)
    return out


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
    from .quality import hex8_scaled_jacobian
    from .transfinite import Refinement, mesh_blocks

    subset = np.asarray(subset, np.int64)
    refs = refinement or FILL_CHECKS
    if len(subset) == 0:
        return np.ones((len(refs), 0)) if per_resolution else np.ones(0)
    # only the subset's vertices: the mesher projects every wall vertex it is given
    used, hexes = np.unique(blocks.hexes[subset], return_inverse=True)
    sub = BlockStructure(
        vertices=blocks.vertices[used], hexes=hexes.reshape(-1, 8), vertex_on_surface=blocks.vertex_on_surface[used],
        face_boundary=blocks.face_boundary[subset], axis_kind=blocks.axis_kind[subset],
        block_radius=blocks.block_radius[subset], block_node=blocks.block_node[subset],
        block_segment=blocks.block_segment[subset], block_layer=blocks.block_layer[subset],
        boundary_names=dict(blocks.boundary_names),
    )
    out = np.ones((len(refs), len(subset)))
    folded = np.zeros((len(refs), len(subset)))
    for r, counts in enumerate(refs):
        ref = Refinement(around=counts[0], core=counts[0], ring=counts[1], layer=counts[2], element_length=counts[3], first_layer=0.02 / counts[4])
        sm = mesh_blocks(sub, project, ref, signed_distance=distance, intersect_lines=intersect_lines)
        sj = hex8_scaled_jacobian(sm.points, sm.cells)
        np.minimum.at(out[r], sm.cell_block, sj)
        # per element of the block at this resolution: each resolution weighs the same
        # each inverted element counts one, less its scaled Jacobian: fewer folds first, then shallower
        np.add.at(folded[r], sm.cell_block, (np.minimum(sj, 0.0) - (sj <= 0)) / np.prod(sm.block_counts, axis=1)[sm.cell_block])
    # a folded block scores minus the share of its elements inverted (less their scaled
    # Jacobians): fewer and shallower folds score higher, any fold lower than every valid block
    if per_resolution:
        return np.where(folded < 0, folded, out)
    return np.where(folded.sum(axis=0) < 0, folded.sum(axis=0), out.min(axis=0))


def fill_score(quality: np.ndarray) -> float:
    """One number for a set of blocks' :func:`fill_quality`: the least value when all are
    valid, else the sum over the folded blocks (always below any valid set's)."""
    quality = np.asarray(quality, float)
    neg = quality[quality < 0]
    return float(neg.sum()) if len(neg) else float(quality.min(initial=1.0))


def write_bad_blocks(blocks: BlockStructure, bad: np.ndarray, path) -> Path:
    """Write the given blocks (with their neighbours for context) to a VTU file."""
    from ..io.atomic import atomic_path

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
