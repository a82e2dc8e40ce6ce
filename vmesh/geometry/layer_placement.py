"""Boundary-layer node lines and the exact first-layer height.

A boundary-layer *node line* runs from a wall node across the boundary-layer elements to
the layer's inner node (the lattice line along the layer axis). :func:`place_first_layer`
re-places the nodes of every line, after the optimiser, so that the first element has the
asked height along the wall normal; :func:`offset_layer` puts the layer's inner nodes at a
given thickness from the wall (an offset of the wall rather than of the block corners) and
carries the move into the ring. Both step lines back where an element would suffer.
"""

from __future__ import annotations

import numpy as np



def _local_faces(cells: np.ndarray, p: int, faces: np.ndarray, owners: np.ndarray) -> np.ndarray:
    """Local face index (0..5, as :func:`~vmesh.io.export.tensor_faces`) of each boundary
    face (``(k, (p+1)^2)`` node ids) in its owning element, -1 where it is none of them."""
    from ..io.export import face_corner_ids, tensor_faces

    corners = tensor_faces(p)[:, face_corner_ids(p)]  # (6, 4)
    own = np.sort(cells[owners][:, corners], axis=2)  # (k, 6, 4)
    hit = (own == np.sort(faces[:, face_corner_ids(p)], axis=1)[:, None, :]).all(axis=2)
    return np.where(hit.any(axis=1), hit.argmax(axis=1), -1)


def _face_partners(cells: np.ndarray, p: int, members: np.ndarray) -> np.ndarray:
    """For each (member element, local face) pair, flattened as ``6 i + f``, the entry of the
    member that shares the face (-1: none among ``members``)."""
    from ..io.export import face_corner_ids, tensor_faces

    corners = tensor_faces(p)[:, face_corner_ids(p)]
    keys = np.sort(cells[members][:, corners], axis=2).reshape(-1, 4)
    partner = np.full(len(keys), -1, np.int64)
    if len(keys) == 0:
        return partner
    from ..repair import _row_order  # packed-key sort: np.unique(axis=0) is ~10x slower here

    order, new = _row_order(keys)
    same = ~new[1:]
    a, b = order[:-1][same], order[1:][same]
    partner[a], partner[b] = b, a
    return partner


def layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, in_layer, max_elements=256):
    """The boundary-layer node lines: from every wall node, the nodes of the lattice line
    that leaves the wall across the boundary-layer elements up to the layer's inner face.

    Parameters
    ----------
    cells : (m, (p+1)^3) node ids in tensor order
    p : int
        Element order.
    boundary_faces, boundary_ids, boundary_cells
        As :class:`~vmesh.mesh.HexMesh` (wall: id 0).
    in_layer : (m,) bool
        Elements of the boundary-layer blocks.
    max_elements : int
        Elements followed along each line (1: the first element only, no face pairing).

    Returns
    -------
    lines : (L, N + 1) int64
        Node ids from the wall node (column 0) inwards, padded with -1 (unique rows).
    elements : (L,) int64
        Elements along each line (its length is ``elements * p + 1``).
    """
    from ..io.export import tensor_faces

    cells = np.asarray(cells)
    wall = np.flatnonzero(np.asarray(boundary_ids) == 0)
    owners = np.asarray(boundary_cells)[wall]
    local = _local_faces(cells, p, np.asarray(boundary_faces)[wall], owners)
    keep = (local >= 0) & in_layer[owners]
    owners, local = owners[keep], local[keep]
    members = np.flatnonzero(in_layer)
    position = np.full(len(cells), -1, np.int64)
    position[members] = np.arange(len(members))
    # the face pairs carry a line into the next element: not needed for first elements only
    partner = _face_partners(cells, p, members) if max_elements > 1 else None
    tf = tensor_faces(p)
    nf = tf.shape[1]
    cell = np.repeat(owners, nf)
    face = np.repeat(local, nf)
    at = np.tile(np.arange(nf), len(owners))
    columns = [cells[cell, tf[face, at]]]
    active = np.ones(len(cell), bool)
    elements = np.zeros(len(cell), np.int64)
    for k in range(max_elements):
        stride = (p + 1) ** (face // 2) * np.where(face % 2 == 0, 1, -1)
        base = tf[face, at]
        for j in range(1, p + 1):
            columns.append(np.where(active, cells[cell, base + j * stride], -1))
        elements += active
        if k + 1 == max_elements:
            break
        nxt = partner[6 * np.maximum(position[cell], 0) + (face ^ 1)]
        active &= nxt >= 0
        if not active.any():
            break
        last = columns[-1]
        cell = np.where(active, members[np.maximum(nxt, 0) // 6], cell)
        face = np.where(active, np.maximum(nxt, 0) % 6, face)
        hit = cells[cell[:, None], tf[face]] == last[:, None]
        at = np.where(active, hit.argmax(axis=1), at)
    lines = np.stack(columns, axis=1)
    from ..repair import _row_order  # np.unique(lines, axis=0, return_index=True), ~5x faster

    order, new = _row_order(lines)
    first = order[new]
    return lines[first], elements[first]


def wall_normals(points, boundary_faces, boundary_ids, p) -> np.ndarray:
    """(n, 3) unit normals into the vessel at the wall nodes (zero elsewhere): the sum of the
    vector areas of the wall's sub-quadrilaterals (the quads of each face's node lattice)
    around each node, i.e. the area-weighted normal of the wall quads."""
    faces = np.asarray(boundary_faces)[np.asarray(boundary_ids) == 0]
    n = p + 1
    a, b = np.meshgrid(np.arange(p), np.arange(p), indexing="xy")
    q00 = (a + n * b).ravel()
    loop = np.stack([q00, q00 + 1, q00 + 1 + n, q00 + n], axis=1)  # (p^2, 4), outward like the face
    quads = faces[:, loop].reshape(-1, 4)
    x = points[quads]
    area = 0.5 * np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])
    out = np.zeros((len(points), 3))
    for c in range(4):
        np.add.at(out, quads[:, c], -area)  # outward face normals: into the vessel is minus
    norm = np.linalg.norm(out, axis=1)
    return np.divide(out, norm[:, None], out=np.zeros_like(out), where=norm[:, None] > 0)


def cap_normals(points, boundary_faces, boundary_ids, p) -> np.ndarray:
    """(n, 3) unit normal of the cap plane (inlet or outlet face set) at each of its nodes,
    zero elsewhere."""
    out = np.zeros((len(points), 3))
    faces, ids = np.asarray(boundary_faces), np.asarray(boundary_ids)
    corners = faces[:, [0, p, (p + 1) ** 2 - 1, p * (p + 1)]]
    for bid in np.unique(ids[ids > 0]):  # a few open ends
        sel = ids == bid
        q = points[corners[sel]]
        normal = np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]).sum(axis=0)
        out[np.unique(faces[sel])] = normal / max(np.linalg.norm(normal), 1e-300)
    return out


def _ratios(r: np.ndarray, n: int) -> np.ndarray:
    """Growth ratios q with ``1 + q + ... + q**(n-1) = r`` (vectorised bisection on log q)."""
    lo = np.full(len(r), -20.0 / max(n, 1))
    hi = np.full(len(r), 20.0 / max(n - 1, 1))
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        small = np.abs(mid) < 1e-12
        s = np.where(small, float(n), np.expm1(n * mid) / np.where(small, 1.0, np.expm1(mid)))
        below = s < r
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.exp(0.5 * (lo + hi))


def _graded_curve(x0, d, xn, first, n, p, kind, samples=48):
    """Nodes of lines from ``x0`` to ``xn`` leaving ``x0`` along ``d`` (a quadratic Bézier
    curve tangent to ``d``), spaced by arc length as ``n`` elements of order ``p`` whose
    first is ``first`` long (then straight along ``d``, so its far node is exactly at
    ``x0 + first d``) and the rest grow geometrically to the end."""
    from .transfinite import element_boundaries, with_order

    ctrl = x0 + 0.5 * np.einsum("ij,ij->i", xn - x0, d)[:, None] * d
    s = np.linspace(0.0, 1.0, samples)[None, :, None]
    curve = (1 - s) ** 2 * x0[:, None] + 2 * s * (1 - s) * ctrl[:, None] + s**2 * xn[:, None]
    arc = np.concatenate([np.zeros((len(x0), 1)), np.cumsum(np.linalg.norm(np.diff(curve, axis=1), axis=2), axis=1)], axis=1)
    total = arc[:, -1]
    q = _ratios(total / first, n)
    u = with_order(element_boundaries(n, q), p, kind) * total[:, None]  # (L, n p + 1)
    # the arc-length targets on the sampled polyline, row by row
    k = np.clip((arc[:, None, :] <= u[:, :, None]).sum(axis=2) - 1, 0, samples - 2)
    a0, a1 = np.take_along_axis(arc, k, 1), np.take_along_axis(arc, k + 1, 1)
    w = np.clip((u - a0) / np.maximum(a1 - a0, 1e-300), 0.0, 1.0)[..., None]
    c0 = np.take_along_axis(curve, k[..., None], 1)
    c1 = np.take_along_axis(curve, k[..., None] + 1, 1)
    out = c0 + w * (c1 - c0)
    out[:, : p + 1] = x0[:, None] + u[:, : p + 1, None] * d[:, None]
    out[:, -1] = xn
    return out


def _line_directions(X, lines, normals, caps, p):
    """Two directions for the first element of each line, and the lines left as they are.

    ``d``: the wall normal, except at a wall node with several lines (where layer blocks of
    different orientation meet): the line's own first edge, so that the lines stay apart.
    ``own``: the line's own first edge (the fallback where ``d`` would spoil an element). On
    a cap (inlet/outlet rim) both keep only their component in the cap plane, so that the
    cap stays plane. ``shared``: lines with a node (besides their inner end) on another line."""
    x0 = X[lines[:, 0]]
    wall_node, count = np.unique(lines[:, 0], return_counts=True)
    several = np.isin(lines[:, 0], wall_node[count > 1])
    own = X[lines[:, p]] - x0
    c = caps[lines[:, 1]]
    out = []
    for d in (np.where(several[:, None], own, normals[lines[:, 0]]), own):
        d = d - np.einsum("ij,ij->i", d, c)[:, None] * c
        out.append(d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None])
    inner = lines[:, 1:-1]
    ids, counts = np.unique(inner[inner >= 0], return_counts=True)
    shared = np.isin(lines[:, 1:], ids[counts > 1]).any(axis=1)
    return out[0], out[1], several, shared


def _placed(X0, lines, elements, d, n0, height, p, kind, first_only=False):
    """Node positions with every line whose first element can be ``height`` thick along the
    wall normal ``n0`` when it leaves the wall along ``d`` re-placed, and which lines those
    are: the whole line (:func:`_graded_curve`), or with ``first_only`` the first element
    alone (its far node moves along ``d``; the rest of the line stays)."""
    cos = np.einsum("ij,ij->i", d, n0)
    first = height / np.maximum(cos, 1e-3)
    end = np.minimum(np.where(first_only, 2, elements), elements) * p
    x0 = X0[lines[:, 0]]
    reach = np.einsum("ij,ij->i", X0[lines[np.arange(len(lines)), end]] - x0, d)
    ok = (cos > 0.5) & (elements >= (2 if first_only else 1)) & (reach > first * 1.01)
    X = X0.copy()
    if first_only:
        from .transfinite import reference_points

        t = reference_points(p, kind)[1:]  # the first element's nodes off the wall, along d
        sel = np.flatnonzero(ok)
        X[lines[sel, 1 : p + 1]] = x0[sel, None] + (first[sel, None] * t[None, :])[..., None] * d[sel, None]
        return X, ok
    for n in np.unique(elements[ok]):
        sel = np.flatnonzero(ok & (elements == n))
        ids = lines[sel, : n * p + 1]
        X[ids[:, 1:-1]] = _graded_curve(X0[ids[:, 0]], d[sel], X0[ids[:, -1]], first[sel], int(n), p, kind)[:, 1:-1]
    return X, ok


def place_first_layer(points, cells, p, boundary_faces, boundary_ids, boundary_cells, in_layer, height, kind="gauss_lobatto", floor=0.3):
    """Re-place the nodes of every boundary-layer node line so that its first element is
    ``height`` thick along the wall normal and the others grow geometrically to the layer's
    inner node (which, like the wall node, stays).

    The first node off the wall goes to ``x0 + height d / (d . n)`` (``n`` the area-weighted
    wall normal, ``d`` the line's first direction, see :func:`_line_directions`): its
    wall-normal distance is exactly ``height``. Where that would harm an element (see
    :func:`_settle`), the line of that element whose first node moved farthest steps back: to its first element alone re-placed (the rest of the line as the
    optimiser left it), then along its own first direction (the same wall-normal height, a
    longer first edge), then to its spacing as it was; repeated until no element does.

    Returns
    -------
    X : (n, 3) ndarray
        The new node positions.
    info : dict
        Line counts: ``lines``, ``placed`` (along the normal), ``first_element_only`` and
        ``own_direction`` (the fallbacks), ``reverted`` (unchanged to keep elements valid), ``unplaced`` (unchanged:
        shared nodes, no room or too oblique), ``several`` (at wall nodes with several lines);
        the minimum scaled Jacobian of the touched elements before and after.
    """
    X0 = np.asarray(points, float)
    cells = np.asarray(cells)
    lines, elements = layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, np.asarray(in_layer, bool))
    if len(lines) == 0:
        return X0.copy(), {"lines": 0}
    normals = wall_normals(X0, boundary_faces, boundary_ids, p)
    d, own, several, shared = _line_directions(X0, lines, normals, cap_normals(X0, boundary_faces, boundary_ids, p), p)
    n0 = normals[lines[:, 0]]
    # the tiers a line steps through: the whole line from the wall normal, its first element
    # alone along the normal, then along its own direction, then as it was
    tiers = [_placed(X0, lines, elements, d, n0, height, p, kind), _placed(X0, lines, elements, d, n0, height, p, kind, True),
             _placed(X0, lines, elements, own, n0, height, p, kind, True), (X0, np.ones(len(lines), bool))]
    last = len(tiers) - 1
    possible = np.stack([t[1] & ~shared for t in tiers[:-1]] + [np.ones(len(lines), bool)], axis=1)
    tier = possible.argmax(axis=1)
    # the nodes each line moves: all but its wall node and inner end
    moving = lines[:, 1:].copy()
    moving[np.arange(len(lines)), elements * p - 1] = -1
    X, tier, before, after = _settle(X0, cells, moving, [t[0] for t in tiers], possible, tier, lines[:, p], p, kind, floor)
    start = possible.argmax(axis=1)
    info = {"lines": len(lines), "placed": int((tier == 0).sum()), "first_element_only": int((tier == 1).sum()), "own_direction": int((tier == 2).sum()),
            "reverted": int(((tier == last) & (start < last)).sum()), "unplaced": int((start == last).sum()), "several": int(several.sum()),
            "sj_before": float(before.min()) if len(before) else None, "sj_after": float(after.min()) if len(after) else None}
    return X, info


def _settle(X0, cells, moving, tiers, possible, tier, probe, p, kind, floor):
    """Put each line's ``moving`` nodes where its tier says, then step lines back a tier
    until no element suffers: in each element below what it may have (the worst element its
    lines touch before, or ``floor``, whichever is lower: a line through a fold may unfold it
    at some cost to its neighbours; and no element may fold among lines that touched none),
    the line whose
    ``probe`` node moved farthest steps back to its next possible tier (the last tier: as it
    was). Returns the positions, the final tiers and the touched elements' scaled Jacobians
    before and after."""
    from .quality import scaled_jacobian
    from .transfinite import reference_points

    last = len(tiers) - 1
    X = X0.copy()
    for k in range(last + 1):
        nodes = moving[tier == k]
        X[nodes[nodes >= 0]] = tiers[k][nodes[nodes >= 0]]
    line_of = np.full(len(X), -1, np.int64)
    has = moving >= 0
    line_of[moving[has]] = np.broadcast_to(np.arange(len(moving))[:, None], moving.shape)[has]
    touched = np.flatnonzero((line_of[cells] >= 0).any(axis=1))
    ref = reference_points(p, kind)
    before = scaled_jacobian(X0, cells[touched], p, ref)
    on = line_of[cells[touched]]
    worst_of_line = np.full(len(moving), np.inf)
    np.minimum.at(worst_of_line, on[on >= 0], np.broadcast_to(before[:, None], on.shape)[on >= 0])
    allowed = np.minimum(np.where(on >= 0, worst_of_line[np.maximum(on, 0)], np.inf).min(axis=1), floor)
    after = before
    for _ in range(200):
        after = scaled_jacobian(X, cells[touched], p, ref)
        bad = touched[(after < allowed) | ((after <= 0) & (allowed > 0))]
        on = line_of[cells[bad]]
        line = np.maximum(on, 0)
        moved = np.where(on >= 0, np.linalg.norm(X[probe[line]] - X0[probe[line]], axis=-1), -1.0)
        moved[(on >= 0) & (tier[line] == last)] = -1.0
        pick = np.take_along_axis(on, moved.argmax(axis=1)[:, None], 1)[:, 0]
        back = np.unique(pick[moved.max(axis=1) >= 0]) if len(bad) else pick
        if len(back) == 0:
            break
        later = possible[back] & (np.arange(last + 1)[None, :] > tier[back][:, None])
        tier[back] = later.argmax(axis=1)
        for k in range(1, last + 1):
            nodes = moving[back[tier[back] == k]]
            X[nodes[nodes >= 0]] = tiers[k][nodes[nodes >= 0]]
    return X, tier, before, after


def offset_layer(points, cells, p, boundary_faces, boundary_ids, boundary_cells, in_layer, in_ring, thickness, height=None, kind="gauss_lobatto", floor=0.3):
    """Put the inner node of every boundary-layer line at ``thickness`` from its wall node
    along the wall normal, the layer's nodes graded between them (first element ``height``
    along the normal; ``None``: the line's relative spacing), and move the ring's nodes on
    the line's continuation by the inner node's move, fading to zero at the core.

    The transfinite layer is ``thickness`` thick at the block corners only; where the wall
    between them bulges in by more than that (a junction, a narrowing) the wall nodes end up
    beyond the layer's inner face and its elements fold. An offset of the wall cannot.
    Lines step back as in :func:`place_first_layer` (here to where they were).

    Returns
    -------
    X : (n, 3) ndarray
    info : dict
        ``lines``, ``offset`` (moved), ``kept`` (as they were) and the minimum scaled
        Jacobian of the touched elements before and after.
    """
    X0 = np.asarray(points, float)
    cells = np.asarray(cells)
    lines, el = layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, np.asarray(in_layer, bool))
    full, fel = layer_lines(cells, p, boundary_faces, boundary_ids, boundary_cells, np.asarray(in_layer, bool) | np.asarray(in_ring, bool))
    if len(lines) == 0 or len(lines) != len(full):
        return X0.copy(), {"lines": len(lines), "offset": 0, "kept": len(lines)}
    normals = wall_normals(X0, boundary_faces, boundary_ids, p)
    d, _, several, shared = _line_directions(X0, lines, normals, cap_normals(X0, boundary_faces, boundary_ids, p), p)
    rows = np.arange(len(lines))
    # the rows of both sets are sorted by wall node: a line and its continuation share a row
    beyond = np.arange(lines.shape[1])[None, :] > (el * p)[:, None]
    same = ((full[:, : lines.shape[1]] == lines) | beyond).all(axis=1) & (fel > el)
    x0 = X0[lines[:, 0]]
    cos = np.einsum("ij,ij->i", d, normals[lines[:, 0]])
    inner_old = X0[lines[rows, el * p]]
    inner_new = x0 + (thickness / np.maximum(cos, 1e-3))[:, None] * d
    old_first = np.linalg.norm(X0[lines[:, p]] - x0, axis=1) / np.maximum(np.linalg.norm(inner_old - x0, axis=1), 1e-300)
    first = height / np.maximum(cos, 1e-3) if height else old_first * thickness / np.maximum(cos, 1e-3)
    ok = same & ~several & ~shared & (cos > 0.5) & (first * el < thickness / np.maximum(cos, 1e-3))
    Xn = X0.copy()
    for n, m in set(zip(el[ok].tolist(), fel[ok].tolist())):
        sel = np.flatnonzero(ok & (el == n) & (fel == m))
        Xn[full[sel, 1 : n * p]] = _graded_curve(x0[sel], d[sel], inner_new[sel], first[sel], n, p, kind)[:, 1:-1]
        ring = full[sel, n * p : m * p + 1]  # from the layer's inner node to the core
        arc = np.concatenate([np.zeros((len(sel), 1)), np.cumsum(np.linalg.norm(np.diff(X0[ring], axis=1), axis=2), axis=1)], axis=1)
        fade = 1.0 - arc / np.maximum(arc[:, -1:], 1e-300)
        Xn[ring[:, :-1]] = X0[ring[:, :-1]] + fade[:, :-1, None] * (inner_new[sel] - inner_old[sel])[:, None]
    moving = full[:, 1:].copy()
    moving[rows, fel * p - 1] = -1  # the core end stays
    possible = np.stack([ok, np.ones(len(ok), bool)], axis=1)
    tier = possible.argmax(axis=1)
    X, tier, before, after = _settle(X0, cells, moving, [Xn, X0], possible, tier, lines[rows, el * p], p, kind, floor)
    return X, {"lines": len(lines), "offset": int((tier == 0).sum()), "kept": int((tier == 1).sum()),
               "sj_before": float(before.min()) if len(before) else None, "sj_after": float(after.min()) if len(after) else None}
