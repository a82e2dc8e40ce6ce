"""Regular sections centred on the middle of the lumen they cut (opt-in
``build_block_structure.centre_sections``; docs/junctions.md h25/realbuild).

A skeleton that runs off the middle of a wide lumen (a thinned voxel skeleton wandering over
a flattened lumen's medial sheet, a centerline drawn off-centre) tilts its regular sections
with its wandering: turned 30-40 degrees at nodes spaced by the thin side's radius while
their rays reach the wide side's walls 2-3 times as far, neighbouring sections cross inside
the lumen, and the blocks between them stay invalid whatever the fix loop does (or the
sections miss the wide side's wall). The middle of the lumen a section cuts does not wander:
moving each lopsided regular node to the middle of its section's chords (as a junction's
half-sections meet at its walls' centre, :meth:`~.junctions._Junctions._junction_centre`)
straightens the skeleton and the tilts with it (the generated flattened tube of
``tests/flat_vessels.py``). A thin handle (pillar) through a round lumen is another cause
of crossing sections, which centring does not remove (docs/junctions.md h25/realbuild).
"""

from __future__ import annotations

import numpy as np

from .. import cross_sections as cs

#: Centring passes: a node's normal (the bisector of its segments) changes as its
#: neighbours move, and the chords' middle of a lopsided section is reached from afar in
#: a few steps (each step is exact for a round lumen, nearly so for an elliptic one).
CENTRE_PASSES = 4


def chord_offsets(R: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """In-plane offset (n, 2) from each section's centre to the middle of its chords.

    ``R`` (n, m) are the rays' lengths at ``angles`` (m,), which hold each direction and
    its opposite (``angles + pi``). Along a chord through the centre in direction ``u``
    the chord's middle lies ``(R(u) - R(-u)) / 2`` ahead; the offset is the least-squares
    point of those projections over the chords."""
    m = len(angles)
    half = m // 2
    u = np.stack([np.cos(angles[:half]), np.sin(angles[:half])], axis=1)  # (half, 2)
    along = 0.5 * (R[:, :half] - R[:, half : 2 * half])  # (n, half)
    normal = u.T @ u  # (2, 2): equal for every section
    return np.linalg.solve(normal, (along @ u).T).T


def centre_regular_nodes(builder, share: float) -> list[int]:
    """Move the builder's regular nodes to the middle of their sections' chords.

    Candidates are the interior nodes of branches whose sections stand at the nodes
    (``br.s == br.arc``: not pushed by a junction's half-sections or a closed end's dome),
    whose rays all reach the wall (cut at touching vessels, :meth:`_own_territory`). A node
    moves, in its section's plane, where the middle lies more than ``share`` of the rays'
    mean length away and deeper in the lumen (a larger signed distance) than the node: a
    lopsided section of a flattened lumen, not the noise of a round one.

    Returns
    -------
    The nodes moved (``builder.topo.pos`` changed there); the caller rebuilds the branches.
    """
    if share <= 0:
        return []
    ang = np.asarray(builder.template.ray_angles, float)
    if len(ang) % 2 or not np.allclose(np.angle(np.exp(1j * (ang[len(ang) // 2 :] - ang[: len(ang) // 2] - np.pi))), 0.0):
        return []  # no opposite rays: no chords
    moved: set[int] = set()
    for _ in range(CENTRE_PASSES):
        idx, nodes, (E1, E2), R = _regular_rays(builder)
        if not idx:
            break
        C = builder.topo.pos[nodes]
        ok = np.all(np.isfinite(R), axis=1)
        if not ok.any():
            break
        R = np.where(ok[:, None], R, 0.0)  # rows with a miss are not moved (``ok``)
        off = chord_offsets(R, ang)
        shift = off[:, :1] * E1 + off[:, 1:] * E2
        # a node chosen once moves on to the middle in the later passes, however little
        far = ok & ((np.linalg.norm(off, axis=1) > share * R.mean(axis=1)) | np.isin(nodes, list(moved)))
        if not far.any():
            break
        new = C[far] + shift[far]
        deeper = np.asarray(builder.sdf(new), float) >= np.asarray(builder.sdf(C[far]), float)
        go = np.flatnonzero(far)[deeper]
        if len(go) == 0:
            break
        builder.topo.pos[nodes[go]] = new[deeper]
        moved.update(nodes[go].tolist())
    return sorted(moved)


def _regular_rays(builder):
    """The regular interior sections standing at their nodes (``br.s == br.arc``: not
    pushed by a junction's half-sections or a closed end's dome), their nodes, the in-plane
    axes of their planes (normal to the bisectors) and their rays (cut at touching vessels),
    one row a section."""
    ang = np.asarray(builder.template.ray_angles, float)
    idx, normals = [], []
    for bi, br in enumerate(builder.topo.branches):
        K = len(br.nodes)
        if K < 3:
            continue
        N = builder._node_normals(br)
        at_node = np.isclose(br.s, br.arc, rtol=0.0, atol=1e-9 * max(br.arc[-1], 1e-300))
        for k in range(1, K - 1):
            if at_node[k]:
                idx.append((bi, k))
                normals.append(N[k])
    if not idx:
        return idx, None, (None, None), None
    nodes = np.array([int(builder.topo.branches[b].nodes[k]) for b, k in idx])
    C = builder.topo.pos[nodes]
    Nn = cs.unit(np.asarray(normals))
    E1 = cs.any_perpendicular(Nn)
    E2 = np.cross(Nn, E1)
    rad = builder.topo.sk.radii[nodes]
    dirs = cs.ray_directions(E1, E2, ang)
    R = builder.cast(np.repeat(C, len(ang), axis=0), dirs.reshape(-1, 3), np.repeat(rad, len(ang))).reshape(len(idx), -1)
    R = builder._own_territory(idx, C, dirs, R, rad)
    return idx, nodes, (E1, E2), R

