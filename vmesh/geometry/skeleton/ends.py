"""Placing the ends of the skeleton (stage 5): at caps, behind flat ends, into rounded ends.

An end is moved to the centre of the cap it belongs to when caps are known;
otherwise the branch is extended along its end tangent to the surface: to the last
full cross-section behind a flat end face (:func:`~.end_faces.flat_end_sections`),
or into a rounded end (an aneurysm dome) down to a depth where the inscribed radius
is ``end_depth`` x the end radius. A cap no end reaches gets a branch of its own
(:func:`_attach_cap`).
"""

from __future__ import annotations

import numpy as np

from .branch_graph import BranchGraph
from .end_faces import end_face_normals, flat_end_sections
from .probe import SdfFunction, center_in_cross_sections, distance_to_wall, evaluate_sdf, plane_basis, sdf_gradient


def _end_tangent(pts: np.ndarray, window: float) -> np.ndarray:
    """Unit direction of the last ``window`` of arclength (principal axis of its points,
    pointing towards the last point); a hook of a few voxels at the very end barely
    turns it."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    from_end = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    near = pts[from_end <= max(window, 1e-12)]
    if len(near) < 3:
        near = pts[-3:]
    centre = near.mean(axis=0)
    direction = np.linalg.svd(near - centre, full_matrices=False)[2][0] if len(near) >= 2 else np.zeros(3)
    if direction @ (near[-1] - near[0]) < 0:
        direction = -direction
    norm = np.linalg.norm(direction)
    return direction / norm if norm > 0 else np.array([1.0, 0.0, 0.0])



def _straight(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points strictly between ``a`` and ``b``, at most ``step`` apart."""
    n = int(np.ceil(np.linalg.norm(b - a) / max(step, 1e-12)))
    t = np.arange(1, n)[:, None] / max(n, 1)
    return a + t * (b - a)


def _bent(a: np.ndarray, via: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points strictly between ``a`` and ``b`` on the two straight lines through ``via``."""
    return np.concatenate([_straight(a, via, step), via[None], _straight(via, b, step)])



def _to_cap(start: np.ndarray, cap, spacing: float, sdf: SdfFunction | None = None) -> np.ndarray:
    """Points strictly between ``start`` and the centre of ``cap``, at most ``spacing``
    apart, arriving along the cap's axis.

    A vessel meets its open end square: the last cross-sections of its branch are parallel
    to the cap. A straight line from a start point off the cap's axis (an end traced along
    one side of the vessel, the junction a short stub leaves) meets the cap at a slant, and
    the sections across it cut along the vessel it runs beside: they find no wall within
    reach. When the line is more than 45 degrees off the axis, the path goes through the
    axis point a cap radius inside (no deeper than ``start``), if that is inside the vessel.
    """
    centre, normal = np.asarray(cap.center, float), np.asarray(cap.normal, float)
    rel = np.asarray(start, float) - centre
    depth = -float(rel @ normal)
    lateral = float(np.linalg.norm(rel + depth * normal))
    if sdf is None or depth <= 0 or lateral <= depth:  # within 45 degrees of the axis
        return _straight(start, centre, spacing)
    via = centre - min(float(cap.radius), depth) * normal
    if np.linalg.norm(via - start) < spacing or evaluate_sdf(sdf, via[None])[0] <= 0:
        return _straight(start, centre, spacing)
    return _bent(start, via, centre, spacing)



#: A cap that needs an end (a flat region whose wall behind is no tube, ``Cap.needs_end``)
#: is matched only to an end that runs into it (the end's tangent within this many degrees
#: of its normal: the axis passes a facet of the side wall, a staircase's terrace, square)
#: or that lies on the region itself (see ``ON_REGION``; whatever its angle).
FACET_END_ANGLE = 45.0

#: An end lies on such a region (and reaches it whatever its angle) when it is within the
#: region's radius of its centre and within this fraction of its own radius: an end on
#: its vessel's axis stands a radius from every facet of its side wall (less the depth of
#: a step), so a terrace beside it is never "under" it, however wide the terrace.
ON_REGION = 0.5


#: A flat region that needs an end and that no end reaches is a facet of the wall of a
#: vessel the skeleton has when its centre lies within this many radii of the skeleton's
#: axis (its segments). A facet of the wall of
#: a tube of radius r lies r from the axis plus the depth of its step, which is below the
#: step's width, itself below the facet's radius < r: so within 2 r; on the generated
#: staircase vessels at most 1.2 r. The end face of a branch the skeleton lacks lies a
#: branch length off the axis (a stub's end face: 1.8 r and more).
FACET_REACH = 1.5


def on_branch_wall(cap, points: np.ndarray, radii: np.ndarray, edges: np.ndarray | None = None) -> bool:
    """Whether a flat region lies on the wall of a vessel the skeleton has.

    Parameters
    ----------
    cap : Cap
        The region (its ``center`` is used).
    points : (n, 3) float array
        Skeleton nodes.
    radii : (n,) float array
        Their radii.
    edges : (e, 2) int array, optional
        Segments between ``points``; default: consecutive points form a polyline.

    Returns
    -------
    bool
        True when the centre lies within ``FACET_REACH`` radii (interpolated along the
        segment) of a segment. A region just beyond a skeleton end counts too: a terraced
        end face is many flat regions, of which one end reaches one; the others are facets
        of that end, not ends of their own.
    """
    points, radii = np.asarray(points, float), np.asarray(radii, float)
    edges = np.c_[np.arange(len(points) - 1), np.arange(1, len(points))] if edges is None else np.asarray(edges, np.int64).reshape(-1, 2)
    if not len(edges):  # single nodes: their distance
        return bool(np.any(np.linalg.norm(points - np.asarray(cap.center, float), axis=1) <= FACET_REACH * radii))
    p0, vec = points[edges[:, 0]], points[edges[:, 1]] - points[edges[:, 0]]
    q = np.asarray(cap.center, float)
    t = np.clip(((q - p0) * vec).sum(1) / np.maximum((vec * vec).sum(1), 1e-300), 0.0, 1.0)
    d = np.linalg.norm(q - p0 - t[:, None] * vec, axis=1)
    r = (1 - t) * radii[edges[:, 0]] + t * radii[edges[:, 1]]
    return bool(np.any(d <= FACET_REACH * r))


def _graph_segments(graph: BranchGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points of every branch of ``graph``, their radii and the segments between
    them (a branch's nodes shared with the branches that meet there, so that an end of
    the graph is an end of the segments)."""
    nodes = [u for u in graph.graph.nodes if graph.degree(u) > 0]  # the nodes on segments first
    if not nodes:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2), np.int64)
    index = {u: i for i, u in enumerate(nodes)}
    pts = [np.array([graph.pos(u) for u in nodes], float).reshape(-1, 3)]
    rad = [np.array([graph.radius(u) for u in nodes], float)]
    edges, n = [], len(nodes)
    for u, v, k in graph.graph.edges(keys=True):
        p, r = graph.polyline(u, v, k, start=u)
        inner = np.arange(n, n + max(len(p) - 2, 0))
        pts.append(p[1:-1])
        rad.append(np.asarray(r, float)[1:-1])
        n += len(inner)
        chain = np.r_[index[u], inner, index[v]]
        edges.append(np.c_[chain[:-1], chain[1:]])
    return np.concatenate(pts), np.concatenate(rad), np.concatenate(edges)


def _match_caps(ends: np.ndarray, end_radii: np.ndarray, caps, tangents: np.ndarray | None = None) -> dict:
    """Greedy one-to-one matching of skeleton ends to caps, nearest first.

    An end matches a cap when it lies inside the vessel behind the cap (depth up
    to a few cap radii along the inward normal) and within a cap radius of its axis.
    Caps that need an end (``needs_end``) choose after the others, and with ``tangents``
    (the ends' outward unit directions) only ends that run into them (``FACET_END_ANGLE``)
    or lie on them (``ON_REGION``).
    """
    pairs = []
    for c, cap in enumerate(caps):
        centre, normal, radius = np.asarray(cap.center, float), np.asarray(cap.normal, float), float(cap.radius)
        rel = centre - ends
        depth = rel @ normal
        lateral = np.linalg.norm(rel - depth[:, None] * normal, axis=1)
        reach = 3.0 * radius + 2.0 * end_radii
        ok = (depth > -0.5 * radius) & (depth < reach) & (lateral < 1.2 * radius)
        # the caps known to be ends choose first; caps here are any objects with a centre,
        # normal and radius (extract_skeleton's API), so needs_end may be absent
        doubt = bool(getattr(cap, "needs_end", False))
        if doubt and tangents is not None:  # an end on the region itself reaches it whatever its direction
            on_region = np.linalg.norm(rel, axis=1) <= np.minimum(radius, ON_REGION * end_radii)
            ok &= (tangents @ normal >= np.cos(np.radians(FACET_END_ANGLE))) | on_region
        for e in np.flatnonzero(ok):
            pairs.append((doubt, float(np.linalg.norm(rel[e])), int(e), c))
    pairs.sort()
    matched, used_ends, used_caps = {}, set(), set()
    for _, _, e, c in pairs:
        if e not in used_ends and c not in used_caps:
            matched[e] = c
            used_ends.add(e)
            used_caps.add(c)
    return matched



def place_ends(graph: BranchGraph, sdf: SdfFunction, spacing: float, caps=None, end_depth: float = 0.5, outside_junction: bool = True) -> dict:
    """Move every end of the skeleton to where the vessel ends.

    * With ``caps`` (objects with ``center``, ``normal``, ``radius``): each end is
      matched to the cap of its open end and extended straight to the cap centre;
      a cap without a skeleton end (its branch was too short to survive thinning)
      gets a new branch from the nearest skeleton point with a path inside the
      vessel to it (:func:`_attach_cap`); caps without one are listed under
      ``unreached``. A cap overlapping a reached one (a cap face detected in two
      parts) needs no end of its own.
    * Other ends are extended along their end tangent to the wall. A flat end
      (the cross-section keeps its full width up to the wall) ends on the axis
      through the centre of the end face, at the last cross-section behind it that
      meets only the side wall (:func:`flat_end_sections`: a quarter radius behind
      a clean face, more behind a tilted, rough or rounded-rim one, as a clipped face
      without a detected cap is); a rounded end (an aneurysm dome, a capsule)
      ends where the inscribed radius has dropped to ``end_depth`` x the radius at
      the medial end.

    A terminal branch's wall-ward tail is cut first (:func:`_trim_end`; ``outside_junction``:
    measured outside its junction's ball, as the extraction does with ``spur_wall``). An end
    marked ``closed_stub`` (a side stub the extraction kept for its wall) is matched to no
    cap: it is extended along its axis like the other free ends.

    Returns the number of ends of each kind (``cap``, ``flat``, ``rounded``, ``added``)
    and, when some cap could not be reached, the list ``unreached`` of their indices;
    caps that need an end (``needs_end``: flat regions that may be facets of the wall) that
    no end reaches and that lie on the wall of a branch (:func:`on_branch_wall`) get no
    branch and are listed under ``not_ends``.
    """
    counts = {"cap": 0, "flat": 0, "rounded": 0, "added": 0}
    ends = [n for n in graph.graph.nodes if graph.degree(n) == 1]
    info = [(node, *_trim_end(graph, node, spacing, outside_junction)) for node in ends]
    caps = list(caps or [])
    matched = {}
    # a side stub the extraction kept for its wall (``closed_stub``: its balls reach no cap)
    # ends where its axis meets the wall (its dome, or a cap there); matched by nearness, it
    # can run into a neighbouring stub's cap and leave its own end out (seed 0 g0012)
    open_ends = [e for e, node in enumerate(ends) if not graph.graph.nodes[node].get("closed_stub")]
    if caps and open_ends:
        end_pos = np.array([graph.pos(ends[e]) for e in open_ends])
        found = _match_caps(end_pos, np.array([info[e][2] for e in open_ends]), caps, np.array([info[e][1] for e in open_ends]))
        matched = {open_ends[j]: c for j, c in found.items()}
    for e, (node, tangent, r_ref) in enumerate(info):
        if e in matched:
            cap = caps[matched[e]]
            _extend(graph, node, np.asarray(cap.center, float), float(cap.radius), spacing, cap=cap, sdf=sdf)
            graph.graph.nodes[node]["end"] = ("cap", matched[e])
            counts["cap"] += 1
    free = [i for e, i in enumerate(info) if e not in matched]
    taken = set(matched.values())
    if free:
        counts_free = _extend_to_wall(graph, sdf, free, spacing, end_depth, caps, taken)
        for key, value in counts_free.items():
            counts[key] += value
    wall = None  # the skeleton's segments, once, for the caps that may be facets of its wall
    for c in sorted(set(range(len(caps))) - taken):
        centre = np.asarray(caps[c].center, float)
        if any(np.linalg.norm(np.asarray(caps[o].center, float) - centre) < caps[o].radius + caps[c].radius for o in taken):
            continue  # overlaps a reached cap: two open ends cannot, it is a piece of that one
        if getattr(caps[c], "needs_end", False) and on_branch_wall(caps[c], *(wall := wall or _graph_segments(graph))):
            counts.setdefault("not_ends", []).append(c)  # a flat facet of the wall no end reaches
            continue
        if _attach_cap(graph, caps[c], c, spacing, sdf):
            counts["added"] += 1
        else:
            counts.setdefault("unreached", []).append(c)
    return counts



def extend_left_ends(graph: BranchGraph, sdf: SdfFunction, nodes, spacing: float, caps=None, end_depth: float = 0.5, outside_junction: bool = True) -> dict:
    """Give ``nodes`` (ends made after :func:`place_ends`, e.g. a junction whose other
    branches were all dropped) their end: trimmed and extended to the wall as a free end.

    Caps an end already reached (an ``end`` mark of ``("cap", c)``) are not taken again;
    another cap the end's axis meets is, as in :func:`place_ends`. Returns the counts of
    ``flat`` / ``rounded`` / ``cap`` ends."""
    nodes = [n for n in nodes if graph.degree(n) == 1]
    if not nodes:
        return {}
    taken = {data["end"][1] for _, data in graph.graph.nodes(data=True) if data.get("end", ("",))[0] == "cap"}
    free = [(node, *_trim_end(graph, node, spacing, outside_junction)) for node in nodes]
    return _extend_to_wall(graph, sdf, free, spacing, end_depth, list(caps or []), taken)


def _trim_end(graph: BranchGraph, node: int, spacing: float, outside_junction: bool = True) -> tuple[np.ndarray, float]:
    """Cut the wall-ward tail off a terminal branch and return its end tangent and radius.

    Near a flat end the medial axis fans out into a cone towards the rim, and the
    thinned curve follows one side of it; the points whose inscribed radius has
    dropped below 85 % of the largest radius near the end are that tail. What
    remains ends on the vessel axis, about a radius before the end face. Only the part
    of the branch outside its junction's inscribed ball is the end's: a short side stub's
    branch starts on its wider parent's axis, and the parent's radius there is no radius
    of the stub (measured with it, the whole stub was taken for a tail and cut off); with
    ``outside_junction`` false the whole window is measured (the extraction before the spur-wall rule).
    """
    (u, v, k), = list(graph.graph.edges(node, keys=True))
    other = graph.other(u, v, node)
    pts, rad = graph.polyline(u, v, k, start=other)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    from_end = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    window = min(float(from_end[0]), 2.0 * float(np.median(rad)) + 2 * spacing)
    tail = np.flatnonzero(from_end <= window)
    if outside_junction and graph.degree(other) >= 3:
        own = tail[np.linalg.norm(pts[tail] - pts[0], axis=1) > rad[0]]
        tail = own if len(own) else tail
    r_ref = float(rad[tail].max())
    keep = tail[rad[tail] >= 0.85 * r_ref]
    last = int(keep[-1]) if len(keep) else len(pts) - 1
    if 0 < last < len(pts) - 1:
        data = graph.graph.edges[u, v, k]
        inner = pts[1:last] if data["start"] == other else pts[1:last][::-1]
        inner_r = rad[1:last] if data["start"] == other else rad[1:last][::-1]
        data["pts"], data["rad"] = inner, inner_r
        graph.graph.nodes[node]["pos"] = pts[last]
        graph.graph.nodes[node]["r"] = float(rad[last])
        pts, from_end = pts[: last + 1], from_end[: last + 1] - from_end[last]
    return _end_tangent(pts, max(2.5 * r_ref, 4 * spacing)), r_ref



def _extend(graph: BranchGraph, node: int, target: np.ndarray, radius: float, spacing: float, direction=None, cap=None, sdf=None) -> None:
    """Move end ``node`` to ``target``, keeping its old position as part of the branch.

    With ``direction`` (the outward axis at the end), branch points that do not lie
    clearly behind ``target`` along it are cut off first: a target set back from an
    end face may lie behind the traced end, and going there and back would fold the
    branch. With ``cap`` (``target`` its centre), the branch arrives along the cap's
    axis (:func:`_to_cap`)."""
    (u, v, k), = list(graph.graph.edges(node, keys=True))
    data = graph.graph.edges[u, v, k]
    target = np.asarray(target, float)
    towards_end = data["start"] != node
    pts = data["pts"] if towards_end else data["pts"][::-1]
    rad = data["rad"] if towards_end else data["rad"][::-1]
    old, old_r = graph.pos(node), graph.radius(node)
    if direction is not None and (old - target) @ direction > -spacing:
        behind = np.flatnonzero((pts - target) @ np.asarray(direction, float) < -spacing)
        keep = behind[-1] + 1 if len(behind) else 0
        pts, rad = pts[:keep], rad[:keep]
        old = pts[-1] if keep else graph.pos(graph.other(u, v, node))
        old_r = rad[-1] if keep else old_r
        extra = _straight(old, target, spacing)
    else:
        extra = np.concatenate([old[None], _to_cap(old, cap, spacing, sdf) if cap is not None else _straight(old, target, spacing)])
    pts = np.concatenate([pts, extra])
    rad = np.concatenate([rad, np.full(len(extra), old_r)])
    data["pts"], data["rad"] = (pts, rad) if towards_end else (pts[::-1].copy(), rad[::-1].copy())
    graph.graph.nodes[node]["pos"] = target
    graph.graph.nodes[node]["r"] = float(radius)



def end_face_ahead(sdf: SdfFunction, origin: np.ndarray, tangent: np.ndarray, r_ref: np.ndarray, spacing: float):
    """Where the axis of the vessel ahead of each end point meets the wall, and whether
    it meets a flat end face there.

    The axis is re-fitted through the centres of two cross-sections a radius apart; the
    wall is looked for up to ``4 x r_ref + 2 x spacing`` ahead. A flat end: the wall's
    face (a plane through many ray hits, :func:`end_face_normals`) faces the axis
    (within 45 degrees) and the section a quarter radius inside it is still full
    (``>= 0.8 x r_ref``); a rounded end (a dome, a bulge, a sac) narrows there, and a
    saddle's wall does not face the axis.

    Returns
    -------
    origin, tangent : (n, 3)
        The centred end points and the re-fitted axes.
    hit : (n,)
        Distance along the axis to the wall (0 where ``has_hit`` is false).
    has_hit : (n,) bool
    wall_point, normal, centre : (n, 3)
        Where the axis meets the wall, the face's outward normal, the centre of the
        section a quarter radius inside.
    section : (n,)
        That section's radius.
    flat : (n,) bool
        The end faces a flat end face.
    """
    origin = np.asarray(origin, float).reshape(-1, 3)
    tangent = np.asarray(tangent, float).reshape(-1, 3)
    r_ref = np.asarray(r_ref, float).reshape(-1)
    # the axis near the end: through the centres of two sections a radius apart
    origin, _ = center_in_cross_sections(sdf, origin, tangent, r_ref)
    behind, _ = center_in_cross_sections(sdf, origin - r_ref[:, None] * tangent, tangent, r_ref)
    axis = origin - behind
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    ok = (length[:, 0] > 0.5 * r_ref) & (np.einsum("ij,ij->i", axis, tangent) > 0.7 * length[:, 0])
    tangent = np.where(ok[:, None], axis / np.maximum(length, 1e-300), tangent)
    reach = 4.0 * r_ref + 2 * spacing
    hit = distance_to_wall(sdf, origin, tangent, reach, samples=24)
    has_hit = np.isfinite(hit)
    hit = np.where(has_hit, hit, 0.0)
    # the wall normal where the axis meets it, from a point a little before the hit
    centre0, _ = center_in_cross_sections(sdf, origin + np.maximum(hit - 0.3 * r_ref, 0)[:, None] * tangent, tangent, r_ref)
    to_wall = distance_to_wall(sdf, centre0, tangent, reach)
    to_wall = np.where(np.isfinite(to_wall), to_wall, 0.3 * r_ref)
    wall_point = centre0 + to_wall[:, None] * tangent
    # the end face's normal from a plane through many face points: the gradient at one
    # point follows every bump of a rough (clipped, smoothed) end face and, tilted, would
    # put the end off the axis
    normal = end_face_normals(sdf, centre0, tangent, r_ref, reach)
    # flat end: facing the axis, and the section a quarter radius inside is still full
    probe = wall_point - 0.25 * r_ref[:, None] * normal
    centre, section = center_in_cross_sections(sdf, probe, normal, r_ref)
    facing = np.einsum("ij,ij->i", normal, tangent) > np.cos(np.radians(45))
    flat = has_hit & facing & (section >= 0.8 * r_ref)
    return origin, tangent, hit, has_hit, wall_point, normal, centre, section, flat


def spurs_at_flat_ends(
    graph: BranchGraph, sdf: SdfFunction, spacing: float, spurs, caps=(), rays: int = 16, max_half_chord: float = 1.6,
    max_wall_angle: float = 30.0,
) -> np.ndarray:
    """Which terminal branches end at a flat end face of a tube of their own: a vessel's
    end, however short past its junction, not a bulge, a saddle, a sac or a terrace.

    ``spurs`` lists ``(u, v, key, tip, base)``; the end's radius is the largest along the
    branch past its junction, its axis the branch's last stretch (as :func:`_trim_end`
    measures an end). A spur is such an end when (1) its axis meets a flat end face
    (:func:`end_face_ahead`), (2) the section a quarter radius inside that face lies
    outside the junction's inscribed ball (the vessel has a cross-section of its own past
    the junction; the fan of the medial axis towards the rim of a flat end forks inside
    it) and (3) all ``rays`` in-plane rays of that section meet side wall (within
    ``max_wall_angle`` of parallel to the axis, as :func:`~.end_faces.flat_end_sections`
    tells side wall) within ``max_half_chord`` radii: a tube closed by the face. A terrace
    or facet on a wider vessel's side wall leaves rays running along that vessel; a bulge
    or a sac's dome meets its rays at a slant. A face on one of ``caps`` is left out: every
    cap gets its end from :func:`place_ends` (matched, or a branch attached), as before, and
    a branch kept there besides (two stubs from one junction) can leave the builder a
    junction it cannot block. Two or more branches of one junction held at one face (within
    half a radius) are the medial axis's fan towards the face's rim: none is held. Returns a
    bool array.
    """
    if not spurs:
        return np.zeros(0, bool)
    tips, tangents, radii, junctions, junction_radii = [], [], [], [], []
    for u, v, key, tip, base in spurs:
        pts, rad = graph.polyline(u, v, key, start=base)
        r_ref = float(rad[1:].max())
        tips.append(pts[-1])
        radii.append(r_ref)
        tangents.append(_end_tangent(pts, max(2.5 * r_ref, 4 * spacing)))
        junctions.append(pts[0])
        junction_radii.append(rad[0])
    radii = np.array(radii)
    *_, wall_point, normal, centre, _, flat = end_face_ahead(sdf, np.array(tips), np.array(tangents), radii, spacing)
    free = np.array([not any(_on_cap_face(w, cap) for cap in caps) for w in wall_point], bool)
    own = np.linalg.norm(centre - np.array(junctions), axis=1) > np.array(junction_radii)
    e1, e2 = plane_basis(normal)
    ang = 2 * np.pi * np.arange(rays) / rays
    dirs = (np.cos(ang)[None, :, None] * e1[:, None, :] + np.sin(ang)[None, :, None] * e2[:, None, :]).reshape(-1, 3)
    origins = np.repeat(centre, rays, axis=0)
    chord = distance_to_wall(sdf, origins, dirs, np.repeat(max_half_chord * radii, rays))
    found = np.isfinite(chord) & (chord > 0)
    back = np.repeat(0.05 * radii, rays)  # the wall normal just inside the hit
    wall = sdf_gradient(sdf, origins + (np.where(found, chord, 0.0) - back)[:, None] * dirs, back)
    along = np.abs(np.einsum("ij,ij->i", wall, np.repeat(normal, rays, axis=0)))
    tube = (found & (along < np.sin(np.radians(max_wall_angle)))).reshape(len(spurs), rays).all(axis=1)
    held = flat & own & tube & free
    # Several branches of one junction at one face are the medial axis's fan towards the
    # face's rim, not vessels of their own: none of them is held.
    base = np.array([s[4] for s in spurs])
    near = np.linalg.norm(centre[:, None, :] - centre[None, :, :], axis=2) < 0.5 * radii[:, None]
    fan = ((base[:, None] == base[None, :]) & near & held[None, :]).sum(axis=1) > 1
    return held & ~fan


def _extend_to_wall(graph: BranchGraph, sdf: SdfFunction, free, spacing: float, end_depth: float, caps=(), taken=None) -> dict:
    """Extend free ends along their tangent: to just behind a flat end face, or into a rounded end.

    An end whose axis meets the wall on a cap not matched yet (its branch bent away
    from the cap's axis) goes to that cap's centre; ``taken`` collects such caps."""
    nodes = [f[0] for f in free]
    r_ref = np.array([f[2] for f in free])
    origin, tangent, hit, has_hit, wall_point, normal, centre, section, flat = end_face_ahead(
        sdf, np.array([graph.pos(n) for n in nodes]), np.array([f[1] for f in free]), r_ref, spacing
    )
    to_face = distance_to_wall(sdf, centre, normal, 0.5 * r_ref + 2 * spacing)
    face = centre + np.where(np.isfinite(to_face), to_face, 0.25 * r_ref)[:, None] * normal
    # the end itself is the last full cross-section behind the face
    flat_end, flat_section, _ = flat_end_sections(sdf, face, normal, tangent, np.where(np.isfinite(section), section, r_ref))
    # rounded end: where the inscribed radius has dropped to end_depth x r_ref, centred
    samples = 32
    t = hit[:, None] * (np.arange(samples + 1) / samples)[None, :]
    d = evaluate_sdf(sdf, (origin[:, None, :] + t[..., None] * tangent[:, None, :]).reshape(-1, 3)).reshape(len(nodes), -1)
    target = end_depth * r_ref
    below = d <= target[:, None]
    first = np.where(below.any(axis=1), np.argmax(below, axis=1), samples)
    j0 = np.maximum(first - 1, 0)
    rows = np.arange(len(nodes))
    d0, d1 = d[rows, j0], d[rows, first]
    frac = np.where(first > 0, np.clip((d0 - target) / np.maximum(d0 - d1, 1e-300), 0, 1), 0.0)
    t_end = t[rows, j0] + frac * (t[rows, first] - t[rows, j0])
    rounded_end, rounded_section = center_in_cross_sections(sdf, origin + t_end[:, None] * tangent, tangent, r_ref)
    counts = {"flat": 0, "rounded": 0, "cap": 0}
    taken = set() if taken is None else taken
    for i, node in enumerate(nodes):
        if not has_hit[i]:
            continue
        on_cap = [
            c
            for c, cap in enumerate(caps)
            if c not in taken and _on_cap_face(wall_point[i], cap)
        ]
        if on_cap:
            cap = caps[on_cap[0]]
            _extend(graph, node, np.asarray(cap.center, float), float(cap.radius), spacing, cap=cap, sdf=sdf)
            graph.graph.nodes[node]["end"] = ("cap", on_cap[0])
            taken.add(on_cap[0])
            counts["cap"] += 1
            continue
        if flat[i]:
            position, radius = flat_end[i], flat_section[i]
            if not np.isfinite(radius):
                radius = section[i]
        else:
            position, radius = rounded_end[i], rounded_section[i]
            if not np.isfinite(radius):
                radius = target[i]
        _extend(graph, node, position, float(radius), spacing, direction=tangent[i])
        graph.graph.nodes[node]["end"] = ("flat",) if flat[i] else ("rounded",)
        counts["flat" if flat[i] else "rounded"] += 1
    return counts



def _on_cap_face(point: np.ndarray, cap) -> bool:
    """Whether a wall point lies on the flat face of ``cap``."""
    rel = np.asarray(point, float) - np.asarray(cap.center, float)
    normal = np.asarray(cap.normal, float)
    depth = float(rel @ normal)
    lateral = float(np.linalg.norm(rel - depth * normal))
    return abs(depth) < 0.3 * float(cap.radius) and lateral < 1.2 * float(cap.radius)



def _attach_cap(graph: BranchGraph, cap, index: int, spacing: float, sdf: SdfFunction | None = None, candidates: int = 64) -> bool:
    """Add a branch from the skeleton to a cap that no end reached.

    The branch starts at the skeleton point nearest to the cap's centre from which a
    straight line to the centre stays inside the vessel (``sdf`` positive along it);
    failing that, from which a line to the point two cap radii behind the cap does
    (the branch then bends there). Ends of other branches are no start: a branch
    continuing through one would carry that end to the wrong cap. Without ``sdf``
    the nearest point is taken. Returns whether a branch was added: none when every
    such path runs through the outside (more than half a cap radius).
    """
    centre = np.asarray(cap.center, float)
    radius = float(cap.radius)
    where, pts = [], []
    for u, v, k, data in graph.graph.edges(keys=True, data=True):
        where += [("branch", u, v, k, i) for i in range(len(data["pts"]))]
        pts.append(data["pts"])
    for n in graph.graph.nodes:
        if graph.degree(n) != 1:
            where.append(("node", n))
            pts.append(graph.pos(n)[None])
    if not where:
        return False
    pts = np.concatenate(pts)
    order = np.argsort(np.linalg.norm(pts - centre, axis=1))[:candidates]
    behind = centre - 2.0 * radius * np.asarray(cap.normal, float)
    pick, via = int(order[0]), None
    if sdf is not None:
        t = (np.arange(1, 17) / 17.0)[None, :, None]
        paths = []  # (depth, weight) along each candidate path, for the direct and the bent one
        for target in (centre, behind):
            probes = pts[order][:, None, :] + t * (target - pts[order][:, None, :])
            if target is behind:  # via the bend: the last stretch, to the cap, too
                probes = np.concatenate([probes, np.broadcast_to(behind + t[0] * (centre - behind), (len(order), 16, 3))], axis=1)
            depth = evaluate_sdf(sdf, probes.reshape(-1, 3)).reshape(len(order), -1)
            # the cap centre is on the surface: the margin asked for fades out over a cap radius
            weight = np.clip(np.linalg.norm(probes - centre, axis=2) / radius, 0.0, 1.0)
            paths.append((depth, weight))
        pick = -1
        # well inside if possible (a path along the wall makes thin nodes); a path that
        # grazes the wall is centred later; one through the outside is no path
        for least in (0.25 * radius, 0.0, -0.5 * radius):
            for (depth, weight), bend in zip(paths, (None, behind)):
                ok = np.flatnonzero((depth >= least * weight).all(axis=1))
                if len(ok):
                    pick, via = int(order[ok[0]]), bend
                    break
            if pick >= 0:
                break
        if pick < 0:
            from .march import attach_by_march

            return attach_by_march(graph, cap, index, spacing, sdf, where, pts)
    location = where[pick]
    base = location[1] if location[0] == "node" else graph.split(*location[1:])
    end = graph.add_node(centre, radius, end=("cap", index))
    start = graph.pos(base)
    if via is None:
        path = _to_cap(start, cap, spacing, sdf)
    else:
        path = _bent(start, via, centre, spacing)
    graph.add_branch(base, end, path, np.full(len(path), radius))
    return True

