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
"""

from __future__ import annotations

import numpy as np

from ..blocks import AXIS_ALONG, BlockStructure
from .transfinite_kernels import _interp_rows
from .transfinite_lattice import Topology, _row_lookup

#: largest turn of an edge end (radians): keeps the bulge well inside the neighbouring blocks
MAX_TURN = np.radians(30.0)
#: a corner whose cross-section faces' angles sum to 2 pi within this tolerance is a planar
#: interior corner, the only kind whose angles are balanced
PLANAR_TOL = 0.15
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


def curved_edges(a: np.ndarray, b: np.ndarray, t: np.ndarray, turn: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Nodes ``(m, N + 1, 3)`` at the arc-length fractions ``t`` (m, N + 1) of the cubic
    Hermite curves from ``a`` to ``b`` whose tangents are the chord turned by ``turn``
    (m, 2) towards ``normal`` at the start and away from it at the end."""
    chord = b - a
    length = np.linalg.norm(chord, axis=1, keepdims=True)
    d = chord / np.maximum(length, 1e-300)
    t0 = length * (np.cos(turn[:, :1]) * d + np.sin(turn[:, :1]) * normal)
    t1 = length * (np.cos(turn[:, 1:]) * d - np.sin(turn[:, 1:]) * normal)
    s = np.linspace(0.0, 1.0, _SAMPLES + 1)[None, :, None]
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    curve = h00 * a[:, None] + h10 * t0[:, None] + h01 * b[:, None] + h11 * t1[:, None]
    arc = np.concatenate([np.zeros((len(a), 1)), np.cumsum(np.linalg.norm(np.diff(curve, axis=1), axis=2), axis=1)], axis=1)
    arc /= np.maximum(arc[:, -1:], 1e-300)
    out = _interp_rows(t, arc, curve)
    out[:, 0], out[:, -1] = a, b
    return out
