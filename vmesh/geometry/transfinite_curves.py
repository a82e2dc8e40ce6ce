"""Curved block edges inside the cross-sections of the O-grid.

The block corners of a cross-section are joined by straight edges, so the core is a
polygon (a square in a tube) and so is the interface between ring and boundary layer.
Where such an interface turns at a corner, the elements around the corner share the
angles badly: at a core corner one core element takes 90° and the two ring elements
135° each (scaled Jacobian sin 135° = 0.71); at a ring/boundary-layer corner the ring
elements take 67.5° and the boundary-layer ones 112.5°.

Curving the interface edges balances them: at every interior corner of an interface
each of the two interface edges leaving it turns by half the difference between the
angle its inner side has and the share it should have, ``2 pi n_in / (n_in + n_out)``
for ``n_in`` inner and ``n_out`` outer block faces at the corner (120° for the core
element at a core corner, a circle-like 180° at the corners of a ring). An edge becomes
the cubic Hermite curve with those end tangents, in the plane of the cross-section, and
its nodes keep their spacing by arc length. The block corners do not move, so junction
half-sections and any other layout of corners are curved by the same rule; a corner whose
faces do not close a planar full turn is left alone.

Edges along the skeleton (:func:`along_tangents`) follow the sections too. A straight edge
between a junction's half cross-section and a branch's first section meets the half-plane
at the angle between the half-plane and the branch (60° and more at a crotch): the
elements next to the half-section are sheared to a scaled Jacobian of about the cosine of
that angle, and every section of a bent vessel kinks the node lines. Each along edge
becomes the cubic Hermite arc that turns as much as its two end sections do (the rotation
of one section's normal onto the other's), symmetric about its chord, at most
:data:`MAX_ALONG_TURN` per end: the node lines run on smoothly through the sections and the
tilt of the sections against the chord is shared by both ends. Wall edges are curved the
same way before they are projected, so the boundary layer follows. At a junction's spine
the two half-planes of a branch's end ask for different turns: the bulges of the edges are
averaged over the blocks they share (:data:`SMOOTH_ROUNDS` times), then the turns of a
block's edges are scaled down until the bulges of any two of them differ by at most
:data:`ALIKE` times their distance, so a thin core block is not sheared between edges bent
apart. Away from junctions an edge bulges no more than the vessel's own course does between
its two sections (measured on the wall, :func:`_course_bounds`): a tilted section at the end
of a straight run (an SWC corner's mitre) does not bend the run.
"""

from __future__ import annotations

import numpy as np

from ..blocks import AXIS_ALONG, HEX_EDGES, HEX_FACES, BlockStructure
from .transfinite_kernels import _interp_rows
from .transfinite_lattice import Topology, _row_lookup

#: largest turn of an edge end (radians): keeps the bulge well inside the neighbouring blocks
MAX_TURN = np.radians(30.0)
#: a corner whose cross-section faces' angles sum to 2 pi within this tolerance is a planar
#: interior corner, the only kind whose angles are balanced
PLANAR_TOL = 0.15
#: largest turn of an along-skeleton edge's end tangent from its chord (radians); 0 keeps them straight
MAX_ALONG_TURN = np.radians(30.0)
#: largest difference of the bulges of two along edges of a block, × the distance between them
ALIKE = 0.5
#: rounds of averaging the along edges' bulges over their blocks before the :data:`ALIKE` bound
SMOOTH_ROUNDS = 3
#: an along edge away from junctions bulges at most this × the bulge of its vessel's own
#: course (the wall's offset from the segment's wall chords; see :func:`_course_bounds`),
#: scaled to the edge's length: a curved vessel keeps its arc, a straight run into a tilted
#: section (a corner's mitre) gets a straight edge
COURSE_FACTOR = 1.5
#: ... plus this × the blocks' radius: the wall's facets and the projection's tolerance
COURSE_FLOOR = 0.1
#: end turns below this (radians) leave an along-skeleton edge straight
MIN_ALONG_TURN = np.radians(0.5)
#: samples per curve for the arc-length re-spacing of its nodes
_SAMPLES = 64


def section_faces(blocks: BlockStructure, topo: Topology):
    """Unique block faces lying in a cross-section (normal to the block's one axis along
    the skeleton) and the layer of their block: ``(face ids, layers)``."""
    along = blocks.axis_kind == AXIS_ALONG
    b = np.flatnonzero(along.sum(axis=1) == 1)
    ax = np.argmax(along[b], axis=1)
    fid = np.concatenate([topo.block_face[b, 2 * ax], topo.block_face[b, 2 * ax + 1]])
    layer = np.concatenate([blocks.block_layer[b], blocks.block_layer[b]])
    fid, first = np.unique(fid, return_index=True)
    return fid, layer[first]


def edge_turns(blocks: BlockStructure, topo: Topology, V: np.ndarray):
    """Tangent turns of the cross-section interface edges.

    Returns
    -------
    turn : (E, 2) float
        Turn (radians, outward positive) of each unique edge's tangent at its first and
        last vertex; zero for edges that stay straight.
    normal : (E, 3) float
        Unit in-plane direction from the inner to the outer side of each curved edge.
    """
    E = len(topo.edges)
    turn = np.zeros((E, 2))
    normal = np.zeros((E, 3))
    fid, layer = section_faces(blocks, topo)
    if len(fid) == 0:
        return turn, normal
    c = topo.faces[fid][:, [0, 1, 3, 2]]  # corners in cyclic order
    P = V[c]
    prev, nxt = np.roll(P, 1, axis=1) - P, np.roll(P, -1, axis=1) - P
    cosang = np.einsum("fcd,fcd->fc", prev, nxt) / np.maximum(np.linalg.norm(prev, axis=2) * np.linalg.norm(nxt, axis=2), 1e-300)
    angle = np.arccos(np.clip(cosang, -1.0, 1.0))  # (F, 4) corner angles
    nv = len(V)
    total = np.zeros(nv)
    np.add.at(total, c.ravel(), angle.ravel())
    n_faces = np.bincount(c.ravel(), minlength=nv)
    planar = np.abs(total - 2 * np.pi) < PLANAR_TOL
    # the four edges of every section face, their unique ids and the face's layer
    pairs = np.stack([c, np.roll(c, -1, axis=1)], axis=2).reshape(-1, 2)
    eid = _row_lookup(topo.edges, np.sort(pairs, axis=1))
    f_of = np.repeat(np.arange(len(fid)), 4)
    lo = np.full(E, np.iinfo(np.int64).max)
    hi = np.full(E, -1)
    np.minimum.at(lo, eid, layer[f_of])
    np.maximum.at(hi, eid, layer[f_of])
    n_on = np.bincount(eid, minlength=E)
    interior = ~blocks.vertex_on_surface
    ends = topo.edges
    level = np.where((n_on == 2) & (hi == lo + 1) & interior[ends[:, 0]] & interior[ends[:, 1]], lo, -1)
    centre = P.mean(axis=1)
    for a in np.unique(level[level >= 0]):
        edges_a = np.flatnonzero(level == a)
        # corners of this interface with exactly two interface edges (a curve passing through)
        deg = np.bincount(ends[edges_a].ravel(), minlength=nv)
        inner = layer <= a
        n_in = np.bincount(c[inner].ravel(), minlength=nv)
        ang_in = np.zeros(nv)
        np.add.at(ang_in, c[inner].ravel(), angle[inner].ravel())
        want = 2 * np.pi * n_in / np.maximum(n_faces, 1)
        delta = np.where(planar & (deg == 2), np.clip(0.5 * (want - ang_in), -MAX_TURN, MAX_TURN), 0.0)
        turn[edges_a] = delta[ends[edges_a]]
        # inner -> outer direction across each edge, orthogonal to it
        k = np.flatnonzero(level[eid] == a)
        side = np.where(inner[f_of[k]], -1.0, 1.0)[:, None] * centre[f_of[k]]
        acc = np.zeros((E, 3))
        np.add.at(acc, eid[k], side)
        d = V[ends[edges_a, 1]] - V[ends[edges_a, 0]]
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        n = acc[edges_a] - np.einsum("ij,ij->i", acc[edges_a], d)[:, None] * d
        normal[edges_a] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return turn, normal


def along_tangents(blocks: BlockStructure, topo: Topology, V: np.ndarray, project=None):
    """Unit end tangents of the block edges along the skeleton.

    The section normal at each end is the mean unit normal of the cross-section faces (the
    end faces, across the block's one axis along the skeleton) of the blocks sharing the
    edge, oriented along the edge. The tangents are the chord turned by minus and plus half
    the rotation of the first normal onto the second (at most :data:`MAX_ALONG_TURN`); the
    edges' bulges are averaged over the blocks they share (:func:`_smooth_bulges`), then
    scaled down where a block's edges would still bulge apart (:func:`_alike_in_blocks`).
    With ``project`` (points -> closest wall points), edges away from junctions bulge no
    more than the vessel's own course does between the two sections (:func:`_course_bounds`).

    Returns
    -------
    tangent : (E, 2, 3) float
        Tangent at the first and last vertex of each unique edge (pointing from the first
        vertex to the last).
    curved : (E,) bool
        Along-skeleton edges whose tangents turn from their chord.
    """
    E = len(topo.edges)
    acc = np.zeros((E, 2, 3))
    curved = np.zeros(E, bool)
    if MAX_ALONG_TURN <= 0:
        return acc, curved
    edges_of = []  # per axis: the along edges (nb, 4) of its blocks
    along = blocks.axis_kind == AXIS_ALONG
    bsel = np.flatnonzero(along.sum(axis=1) == 1)
    axis = np.argmax(along[bsel], axis=1)
    for a in range(3):
        b = bsel[axis == a]
        if len(b) == 0:
            continue
        H = blocks.hexes[b]
        F0, F1 = V[H[:, HEX_FACES[2 * a]]], V[H[:, HEX_FACES[2 * a + 1]]]  # the two end faces (cyclic corners)
        forward = F1.mean(axis=1) - F0.mean(axis=1)
        normals = []
        for F in (F0, F1):
            n = np.cross(F[:, 2] - F[:, 0], F[:, 3] - F[:, 1])
            n *= np.sign(np.einsum("ij,ij->i", n, forward))[:, None]
            normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
        edges_of.append(topo.block_edge[b, 4 * a: 4 * a + 4])
        for i in range(4 * a, 4 * a + 4):
            e = topo.block_edge[b, i]
            lo, hi = H[:, HEX_EDGES[i, 0]], H[:, HEX_EDGES[i, 1]]  # at the end faces 0 and 1
            up = (lo < hi)[:, None]  # unique edges run from the smaller vertex id
            np.add.at(acc[:, 0], e, np.where(up, normals[0], -normals[1]))
            np.add.at(acc[:, 1], e, np.where(up, normals[1], -normals[0]))
            curved[e] = True
    d = V[topo.edges[:, 1]] - V[topo.edges[:, 0]]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    N0, N1 = (acc[:, k] / np.maximum(np.linalg.norm(acc[:, k], axis=1, keepdims=True), 1e-300) for k in (0, 1))
    # the line turns as much as its end sections do (rotation of N0 onto N1, about w), as a
    # symmetric arc about the chord: the sections' tilt against the chord is shared by both
    # ends, not pushed into an S-bend in the middle
    w = np.cross(N0, N1)
    sin = np.linalg.norm(w, axis=1)
    half = np.minimum(0.5 * np.arctan2(sin, np.einsum("ij,ij->i", N0, N1)), MAX_ALONG_TURN)
    w /= np.maximum(sin, 1e-300)[:, None]
    bend = np.cross(d, w)  # the side the symmetric arc bulges to (N0 turned onto N1 about w)
    bend /= np.maximum(np.linalg.norm(bend, axis=1, keepdims=True), 1e-300)
    half, bend = _smooth_bulges(topo, V, d, half, bend, curved, edges_of)
    if project is not None:
        group = _segment_groups(blocks)
        half = np.where(_near_junctions(blocks, topo, group), half, np.minimum(half, _course_bounds(blocks, topo, V, project, group)))
    acc = _symmetric_tangents(d, bend, half)
    scale = _alike_in_blocks(topo, V, acc, edges_of)
    half = half * scale
    acc = _symmetric_tangents(d, bend, half)
    curved &= (half > MIN_ALONG_TURN) & (np.einsum("ij,ij->i", N0, d) > 0) & (np.einsum("ij,ij->i", N1, d) > 0)
    return acc, curved


def _segment_groups(blocks) -> np.ndarray:
    """Per block, a label shared by the blocks of the same (skeleton node, segment): the
    blocks between one section and the next."""
    return np.unique(np.c_[blocks.block_node, blocks.block_segment], axis=0, return_inverse=True)[1].ravel()


def _near_junctions(blocks, topo, group):
    """Along edges of the segments that reach a junction: there the along edges turn from a
    junction's half-plane to its branch as the crotch asks, not as the vessel's course does.
    A junction's corners are those of blocks inside it (no segment) or shared by the blocks
    of three or more segments (a regular section is shared by two); every block of a
    (node, segment) group touching one is near."""
    nb = len(blocks.hexes)
    pairs = np.unique(np.c_[blocks.hexes.ravel(), np.repeat(blocks.block_segment, 8)], axis=0)
    n_seg = np.bincount(pairs[:, 0], minlength=len(blocks.vertices))
    corner = n_seg >= 3
    corner[blocks.hexes[blocks.block_segment < 0].ravel()] = True
    touched = np.zeros(group.max() + 1 if nb else 0, bool)
    touched[group[corner[blocks.hexes].any(axis=1)]] = True
    out = np.zeros(len(topo.edges), bool)
    out[topo.block_edge[touched[group]].ravel()] = True
    return out


def _course_bounds(blocks, topo, V, project, group):
    """Per edge, the largest end turn (radians) of its symmetric arc that bulges no more
    than the vessel's own course between its two sections.

    The sections' tilt cannot tell a curved vessel from a straight run into a tilted section
    (a corner's mitre, a chamfered SWC corner): both rotate the normals. The wall can. The
    wall corners of both sections lie on the wall, so the wall's offset from the midpoint of
    each wall chord of a segment (``project(M) - M``) is the sagitta of the wall along it:
    along a bend the outer and the inner wall both bulge away from the bend's centre, by
    about the course's own sagitta; along a straight run, twisted or tilted sections alike,
    the offsets cancel in their mean. Each along edge of the segment may bulge
    :data:`COURSE_FACTOR` × the mean offset's length (× its length over the wall chords'
    mean length) plus :data:`COURSE_FLOOR` × its blocks' radius."""
    E = len(topo.edges)
    bound = np.full(E, np.inf)
    along = blocks.axis_kind == AXIS_ALONG
    bsel = np.flatnonzero((along.sum(axis=1) == 1) & (blocks.block_segment >= 0))
    if len(bsel) == 0:
        return bound
    axis = np.argmax(along[bsel], axis=1)
    cols = 4 * axis[:, None] + np.arange(4)[None, :]
    edges = np.take_along_axis(topo.block_edge[bsel], cols, axis=1)  # (nb, 4) along edges
    group = group[bsel]
    ng = group.max() + 1
    e_flat, g_flat = edges.ravel(), np.repeat(group, 4)
    e_flat, first = np.unique(e_flat, return_index=True)
    g_flat = g_flat[first]
    a, b = V[topo.edges[e_flat, 0]], V[topo.edges[e_flat, 1]]
    L = np.linalg.norm(b - a, axis=1)
    wall = blocks.vertex_on_surface[topo.edges[e_flat, 0]] & blocks.vertex_on_surface[topo.edges[e_flat, 1]]
    M = 0.5 * (a[wall] + b[wall])
    offset = np.zeros((ng, 3))
    np.add.at(offset, g_flat[wall], project(M) - M)
    n_wall = np.bincount(g_flat[wall], minlength=ng)
    L_wall = np.bincount(g_flat[wall], weights=L[wall], minlength=ng)
    has = n_wall > 0
    sag = np.full(ng, np.inf)
    sag[has] = np.linalg.norm(offset[has], axis=1) / n_wall[has]
    L_ref = np.where(has, L_wall / np.maximum(n_wall, 1), 1.0)
    radius = np.full(E, np.inf)
    np.minimum.at(radius, topo.block_edge[bsel].ravel(), np.repeat(blocks.block_radius[bsel], 12))
    allowed = COURSE_FACTOR * sag[g_flat] * L / np.maximum(L_ref[g_flat], 1e-300) + COURSE_FLOOR * radius[e_flat]
    bound[e_flat] = np.arcsin(np.clip(4.0 * allowed / np.maximum(L, 1e-300), 0.0, 1.0))
    return bound


def _symmetric_tangents(d, bend, half):
    """End tangents (E, 2, 3) of symmetric arcs about the chords ``d``, turned by ``half``
    towards the unit side ``bend`` (orthogonal to ``d``) at the start and back at the end."""
    c, s = np.cos(half)[:, None], np.sin(half)[:, None]
    return np.stack([c * d + s * bend, c * d - s * bend], axis=1)


def _smooth_bulges(topo, V, d, half, bend, along, edges_of, rounds: int | None = None):
    """The along edges' mid-point bulges averaged over the blocks they share, ``rounds``
    times (:data:`SMOOTH_ROUNDS`): returns the new ``(half, bend)``.

    Next to a junction's spine the edges of one block ask for turns towards different
    sides (each from its own half-plane to the branch); bounded alone
    (:func:`_alike_in_blocks`) they would all be scaled down to a few degrees and the
    crotch elements stay sheared at the half-plane. Averaged, neighbouring edges bend alike
    and keep most of the turn."""
    rounds = SMOOTH_ROUNDS if rounds is None else rounds
    if rounds <= 0 or not along.any():
        return half, bend
    L = np.linalg.norm(V[topo.edges[:, 1]] - V[topo.edges[:, 0]], axis=1)
    bulge = np.where(along[:, None], (0.25 * L * np.sin(half))[:, None] * bend, 0.0)
    for _ in range(rounds):
        acc = np.zeros_like(bulge)
        cnt = np.zeros(len(L))
        for edges in edges_of:
            mean = bulge[edges].mean(axis=1)  # (nb, 3) per block
            np.add.at(acc, edges.ravel(), np.repeat(mean, 4, axis=0))
            np.add.at(cnt, edges.ravel(), 1.0)
        ok = cnt > 0
        bulge[ok] = acc[ok] / cnt[ok, None]
        bulge -= np.einsum("ij,ij->i", bulge, d)[:, None] * d  # across the chord only
    size = np.linalg.norm(bulge, axis=1)
    new_half = np.where(along, np.arcsin(np.clip(4.0 * size / np.maximum(L, 1e-300), 0.0, 1.0)), half)
    new_half = np.minimum(new_half, MAX_ALONG_TURN)
    new_bend = np.where((along & (size > 0))[:, None], bulge / np.maximum(size, 1e-300)[:, None], bend)
    return new_half, new_bend


def _alike_in_blocks(topo, V, tangent, edges_of, rounds: int = 3):
    """Per edge, a factor (<= 1) on its turns so that the along edges of every block bulge
    alike: the difference of two edges' mid-point offsets from their chords stays within
    :data:`ALIKE` times the distance between the edges (a thin core block between edges
    bent apart would be sheared or folded)."""
    L = np.linalg.norm(V[topo.edges[:, 1]] - V[topo.edges[:, 0]], axis=1)
    bulge = (L / 8.0)[:, None] * (tangent[:, 0] - tangent[:, 1])  # Hermite mid-point offset
    scale = np.ones(len(L))
    # each pair of edges against its own distance: a thin block's two sides must bend alike,
    # edges far apart across a wide block may bend apart more (the distances do not change
    # from round to round)
    gaps = []
    for along in edges_of:
        M = 0.5 * (V[topo.edges[along, 0]] + V[topo.edges[along, 1]])
        gaps.append(np.linalg.norm(M[:, :, None] - M[:, None, :], axis=3))
    for _ in range(rounds):
        changed = False
        for along, gap in zip(edges_of, gaps):
            off = scale[along][..., None] * bulge[along]  # (nb, 4, 3)
            diff = np.linalg.norm(off[:, :, None] - off[:, None, :], axis=3)
            ratio = ALIKE * gap / np.maximum(diff, 1e-300)
            ratio[:, np.arange(4), np.arange(4)] = np.inf
            f = np.minimum(1.0, ratio.min(axis=(1, 2)))
            low = f < 1.0 - 1e-9
            if low.any():
                changed = True
                target = scale[along[low]] * f[low, None]  # relative to the offsets as scaled so far
                np.minimum.at(scale, along[low].ravel(), target.ravel())
        if not changed:
            break
    return scale


def hermite_edges(a: np.ndarray, b: np.ndarray, t: np.ndarray, T0: np.ndarray, T1: np.ndarray) -> np.ndarray:
    """Nodes ``(m, N + 1, 3)`` at the arc-length fractions ``t`` (m, N + 1) of the cubic
    Hermite curves from ``a`` to ``b`` with unit end tangents ``T0``, ``T1`` (scaled by
    the chord length)."""
    length = np.linalg.norm(b - a, axis=1, keepdims=True)
    return _hermite_nodes(a, b, t, length * T0, length * T1)


def curved_edges(a: np.ndarray, b: np.ndarray, t: np.ndarray, turn: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Nodes ``(m, N + 1, 3)`` at the arc-length fractions ``t`` (m, N + 1) of the cubic
    Hermite curves from ``a`` to ``b`` whose tangents are the chord turned by ``turn``
    (m, 2) towards ``normal`` at the start and away from it at the end."""
    chord = b - a
    length = np.linalg.norm(chord, axis=1, keepdims=True)
    d = chord / np.maximum(length, 1e-300)
    t0 = length * (np.cos(turn[:, :1]) * d + np.sin(turn[:, :1]) * normal)
    t1 = length * (np.cos(turn[:, 1:]) * d - np.sin(turn[:, 1:]) * normal)
    return _hermite_nodes(a, b, t, t0, t1)


def _hermite_nodes(a, b, t, t0, t1):
    """Nodes of cubic Hermite curves at arc-length fractions ``t`` (end tangents ``t0``, ``t1``)."""
    s = np.linspace(0.0, 1.0, _SAMPLES + 1)[None, :, None]
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    curve = h00 * a[:, None] + h10 * t0[:, None] + h01 * b[:, None] + h11 * t1[:, None]
    arc = np.concatenate([np.zeros((len(a), 1)), np.cumsum(np.linalg.norm(np.diff(curve, axis=1), axis=2), axis=1)], axis=1)
    arc /= np.maximum(arc[:, -1:], 1e-300)
    out = _interp_rows(t, arc, curve)
    out[:, 0], out[:, -1] = a, b
    return out
