"""Compiled kernels of the local hexahedral mesh optimiser (:mod:`vmesh.geometry.optimize`).

The quality functional of a node is the sum, over the corners of its incident (linear,
tensor-order) hexahedra that it belongs to, of Escobar's regularised shape measure

    f = |E|^2 / (3 h(det E)^(2/3)),   h(D) = (D + sqrt(D^2 + 4 delta^2)) / 2,

with ``E`` the corner's three edges (along +i, +j, +k), each divided by its *target*
length (its length in the initial mesh): an ideal corner is orthogonal with its initial
edge lengths, so graded boundary-layer elements stay thin. ``h`` keeps ``f`` finite and
smooth for inverted corners (``det E <= 0``), so the same Newton step untangles.

Moving one node ``x`` changes a corner only through edges that are affine in ``x`` with a
scalar coefficient ``k_a`` (``de_a/dx = k_a I``), and ``det E`` is then affine in ``x``
(a tetrahedron's volume is linear in each vertex). So with ``F = |E|^2`` and
``phi(D) = h(D)^(-2/3) / 3``:

    grad f = phi grad F + F phi' grad D
    Hess f = phi 2 sum(k_a^2) I + phi' (grad F grad D^T + grad D grad F^T) + F phi'' grad D grad D^T

which is exact and costs a few dozen flops per corner: no finite differences.
"""

from __future__ import annotations

import types

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import types as nbtypes
from numba.extending import intrinsic

from .prefetch import ahead
from .trials import least_ratio, order_rows, row_below, trial_quality, trial_quality_guarded, trial_quality_ordered
from .structure import colour_nodes, grow_nodes, incidence, step_caps, target_scales  # re-exported: the stage's structure

#: node kinds: free in 3-D, sliding on the wall (tangent plane, then projection), sliding in a
#: cap plane, fixed, sliding at a fixed distance from the wall (first boundary layer: tangent
#: plane, then put back at that distance)
FREE, WALL, PLANE, FIXED, OFFSET = 0, 1, 2, 3, 4
#: acceptance rules: the functional decreases (untangling); the functional decreases and the
#: incident elements' minimum and sum of scaled Jacobians do not (smoothing a valid mesh)
UNTANGLE, SMOOTH, ESCOBAR = 0, 1, 2
#: Newton trials (t = 1, 1/2, ...) of a smoothing step, and max-min trials of a refused one
#: (4 and 3 cost the mean quality 1e-4 to 3e-4 on the real cases for ~10 % less time)
SMOOTH_TRIALS = 8
CLIMB_TRIALS = 6
#: frame buffers per colour (parallel chunks of nodes)
CHUNKS = 64


def _variant(func, name):
    """``func`` under another name: numba's disk cache is keyed on the function's name and
    signature, not on ``parallel``, so two variants of one function would load each other's
    code (the serial one then ran the parallel code: a thread launch per small colour)."""
    f = types.FunctionType(func.__code__, func.__globals__, name, func.__defaults__, func.__closure__)
    f.__qualname__ = name
    f.__doc__ = func.__doc__
    return f


@nb.njit(cache=True)
def _edge(X, hexes, scale, e, c, a, cx, cy, cz):
    """Edge of corner ``c`` (at ``cx, cy, cz``) of hexahedron ``e`` along axis ``a``, towards
    +a and divided by its target length ``1 / scale[e, a]``."""
    w = hexes[e, c ^ (1 << a)]
    s = (1.0 if ((c >> a) & 1) == 0 else -1.0) * scale[e, a]
    return s * (X[w, 0] - cx), s * (X[w, 1] - cy), s * (X[w, 2] - cz)


@nb.njit(cache=True)
def _corner_edges(X, hexes, scale, e, c):
    """The three scaled edges of corner ``c`` of hexahedron ``e`` (see :func:`_edge`), row by row."""
    n0 = hexes[e, c]
    cx, cy, cz = X[n0, 0], X[n0, 1], X[n0, 2]
    # np.int64(...): an int literal argument would compile a specialisation of its own
    e00, e01, e02 = _edge(X, hexes, scale, e, c, np.int64(0), cx, cy, cz)
    e10, e11, e12 = _edge(X, hexes, scale, e, c, np.int64(1), cx, cy, cz)
    e20, e21, e22 = _edge(X, hexes, scale, e, c, np.int64(2), cx, cy, cz)
    return e00, e01, e02, e10, e11, e12, e20, e21, e22


@nb.njit(cache=True)
def _cofactors(e00, e01, e02, e10, e11, e12, e20, e21, e22):
    """Cofactors of the edge matrix: the gradient of its determinant with respect to each edge."""
    return (
        e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20,
        e21 * e02 - e22 * e01, e22 * e00 - e20 * e02, e20 * e01 - e21 * e00,
        e01 * e12 - e02 * e11, e02 * e10 - e00 * e12, e00 * e11 - e01 * e10,
    )


@nb.njit(cache=True)
def _newton_direction(g0, g1, g2, h00, h01, h02, h11, h12, h22, kind, n0, n1, n2):
    """Newton step ``-H^-1 g`` restricted to the node's allowed moves (all of space, or the
    plane of normal n). A non positive-definite Hessian is shifted until it is."""
    if kind == FREE:
        shift = 0.0
        for _ in range(40):
            a00, a11, a22 = h00 + shift, h11 + shift, h22 + shift
            # Cholesky of [[a00, h01, h02], [h01, a11, h12], [h02, h12, a22]]
            if a00 > 0.0:
                l00 = np.sqrt(a00)
                l10, l20 = h01 / l00, h02 / l00
                s11 = a11 - l10 * l10
                if s11 > 0.0:
                    l11 = np.sqrt(s11)
                    l21 = (h12 - l20 * l10) / l11
                    s22 = a22 - l20 * l20 - l21 * l21
                    if s22 > 0.0:
                        l22 = np.sqrt(s22)
                        y0 = -g0 / l00
                        y1 = (-g1 - l10 * y0) / l11
                        y2 = (-g2 - l20 * y0 - l21 * y1) / l22
                        d2 = y2 / l22
                        d1 = (y1 - l21 * d2) / l11
                        d0 = (y0 - l10 * d1 - l20 * d2) / l00
                        return d0, d1, d2
            scale = abs(h00) + abs(h11) + abs(h22) + 1e-300
            shift = max(2.0 * shift, 1e-6 * scale)
        return 0.0, 0.0, 0.0
    # tangent basis (t, u) of the plane
    if abs(n0) < 0.9:
        tx, ty, tz = 0.0, n2, -n1
    else:
        tx, ty, tz = -n2, 0.0, n0
    tn = np.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx / tn, ty / tn, tz / tn
    ux, uy, uz = n1 * tz - n2 * ty, n2 * tx - n0 * tz, n0 * ty - n1 * tx
    gt = g0 * tx + g1 * ty + g2 * tz
    gu = g0 * ux + g1 * uy + g2 * uz
    Ht = (h00 * tx + h01 * ty + h02 * tz, h01 * tx + h11 * ty + h12 * tz, h02 * tx + h12 * ty + h22 * tz)
    Hu = (h00 * ux + h01 * uy + h02 * uz, h01 * ux + h11 * uy + h12 * uz, h02 * ux + h12 * uy + h22 * uz)
    att = tx * Ht[0] + ty * Ht[1] + tz * Ht[2]
    atu = ux * Ht[0] + uy * Ht[1] + uz * Ht[2]
    auu = ux * Hu[0] + uy * Hu[1] + uz * Hu[2]
    shift = 0.0
    for _ in range(40):
        a, b = att + shift, auu + shift
        det = a * b - atu * atu
        if a > 0.0 and det > 0.0:
            dt = (-gt * b + gu * atu) / det
            du = (-gu * a + gt * atu) / det
            return dt * tx + du * ux, dt * ty + du * uy, dt * tz + du * uz
        shift = max(2.0 * shift, 1e-6 * (abs(att) + abs(auu) + 1e-300))
    return 0.0, 0.0, 0.0


@nb.njit(cache=True)
def _mark(hexes, ptr, inc, v, dirty):
    """Node ``v`` moved: it and every node sharing a hexahedron with it are worth another try."""
    for t in range(ptr[v], ptr[v + 1]):
        e = inc[t] >> 3
        for c in range(8):
            dirty[hexes[e, c]] = True


#: columns of a node's local frame (:func:`frame`), one row per incident hexahedron: the
#: moving corner's three neighbours relative to the node (0:9); the determinant of the moving
#: corner's edge matrix, affine in the node's displacement z (gradient 9:12, value at z = 0
#: 12); for each other moved corner (the neighbour along axis a, from 13 + 6 a): its
#: determinant's gradient (3) and value (1), the product of its two fixed edges' squared
#: lengths (1) and the sum of their scaled squared lengths (1); the squared target scales
#: (31:34) and their product (34); the minimum of the four corners the node does not move (35);
#: then scratch for :func:`node_eval`: per moved corner q its functional's inputs (36 + 9 q:
#: F, D, dF (3), dD (3), diag); then the Jacobian ratio's inputs: the least determinant of
#: the four corners the node does not move (72), their largest magnitude (73) and the
#: element's ratio (min det / max |det| over its 8 corners) where the frame was taken (74);
#: the light pass's row order and per-row minima (75, 76: :func:`.trials.order_rows`)
NL = 77


@nb.njit(cache=True)
def frame(X, hexes, scale, ptr, inc, cq, v, L, ratio=True):
    """Local frame of node ``v`` at its current position into ``L`` (valence, NL); the
    Jacobian ratio's columns (72:75: four more determinants per hexahedron) only with
    ``ratio`` (the taper guard on).

    Moving one node changes 4 corners of each incident hexahedron, and each of their edge
    matrices' determinants is affine in the node's position (a tetrahedron's volume is
    linear in each vertex); the other edges do not move. So everything a trial needs
    except the moving edges' lengths is computed once per node update, not once per trial;
    positions are relative to the node (no cancellation of large coordinates).
    """
    x0, x1, x2 = X[v, 0], X[v, 1], X[v, 2]
    for t in range(ptr[v], ptr[v + 1]):
        e = inc[t] >> 3
        l = inc[t] & 7
        r = t - ptr[v]
        for a in range(3):
            w = hexes[e, l ^ (1 << a)]
            L[r, 3 * a], L[r, 3 * a + 1], L[r, 3 * a + 2] = X[w, 0] - x0, X[w, 1] - x1, X[w, 2] - x2
            L[r, 31 + a] = scale[e, a] * scale[e, a]
        L[r, 34] = scale[e, 0] * scale[e, 1] * scale[e, 2]
        # corner l: det[p0 - z; p1 - z; p2 - z] = det[p] - z . (p1 x p2 + p2 x p0 + p0 x p1),
        # with the edges' signs (an edge runs towards +a)
        s = (1.0 if l & 1 == 0 else -1.0) * (1.0 if l & 2 == 0 else -1.0) * (1.0 if l & 4 == 0 else -1.0)
        det = 0.0
        for d in range(3):
            d1, d2 = (d + 1) % 3, (d + 2) % 3
            c12 = L[r, 3 + d1] * L[r, 6 + d2] - L[r, 3 + d2] * L[r, 6 + d1]
            c20 = L[r, 6 + d1] * L[r, d2] - L[r, 6 + d2] * L[r, d1]
            c01 = L[r, d1] * L[r, 3 + d2] - L[r, d2] * L[r, 3 + d1]
            det += L[r, d] * c12
            L[r, 9 + d] = -s * (c12 + c20 + c01)
        L[r, 12] = s * det
        for a in range(3):
            # corner c = the neighbour along a: its edge along a ends at the node, its edges
            # along b and c (cyclic) are fixed; det = e_a . (e_b x e_c)
            c, b, cc = l ^ (1 << a), (a + 1) % 3, (a + 2) % 3
            n0, wb, wc = hexes[e, c], hexes[e, c ^ (1 << b)], hexes[e, c ^ (1 << cc)]
            sa = 1.0 if (c >> a) & 1 == 0 else -1.0
            sb = 1.0 if (c >> b) & 1 == 0 else -1.0
            sc = 1.0 if (c >> cc) & 1 == 0 else -1.0
            bx, by, bz = sb * (X[wb, 0] - X[n0, 0]), sb * (X[wb, 1] - X[n0, 1]), sb * (X[wb, 2] - X[n0, 2])
            cx, cy, cz = sc * (X[wc, 0] - X[n0, 0]), sc * (X[wc, 1] - X[n0, 1]), sc * (X[wc, 2] - X[n0, 2])
            k = 13 + 6 * a
            gx, gy, gz = sa * (by * cz - bz * cy), sa * (bz * cx - bx * cz), sa * (bx * cy - by * cx)
            L[r, k], L[r, k + 1], L[r, k + 2] = gx, gy, gz
            L[r, k + 3] = -(gx * L[r, 3 * a] + gy * L[r, 3 * a + 1] + gz * L[r, 3 * a + 2])
            nb2, nc2 = bx * bx + by * by + bz * bz, cx * cx + cy * cy + cz * cz
            L[r, k + 4] = nb2 * nc2
            L[r, k + 5] = L[r, 31 + b] * nb2 + L[r, 31 + cc] * nc2
        L[r, 35] = min(min(cq[e, l ^ 3], cq[e, l ^ 5]), min(cq[e, l ^ 6], cq[e, l ^ 7]))
        if not ratio:
            continue
        lo, hi = np.inf, 0.0
        for c in (l ^ 3, l ^ 5, l ^ 6, l ^ 7):
            d = _plain_det(X, hexes, e, c)
            lo, hi = min(lo, d), max(hi, abs(d))
        L[r, 72], L[r, 73] = lo, hi
        for d in (L[r, 12], L[r, 16], L[r, 22], L[r, 28]):
            lo, hi = min(lo, d), max(hi, abs(d))
        L[r, 74] = lo / max(hi, 1e-300)


@nb.njit(cache=True, inline="always")
def _plain_det(X, hexes, e, c):
    """Determinant of the (unscaled) edge matrix of corner ``c`` of hexahedron ``e``: its
    Jacobian up to a constant factor."""
    n0 = hexes[e, c]
    s0 = 1.0 if c & 1 == 0 else -1.0
    s1 = 1.0 if c & 2 == 0 else -1.0
    s2 = 1.0 if c & 4 == 0 else -1.0
    a, b, d = hexes[e, c ^ 1], hexes[e, c ^ 2], hexes[e, c ^ 4]
    ax, ay, az = X[a, 0] - X[n0, 0], X[a, 1] - X[n0, 1], X[a, 2] - X[n0, 2]
    bx, by, bz = X[b, 0] - X[n0, 0], X[b, 1] - X[n0, 1], X[b, 2] - X[n0, 2]
    dx, dy, dz = X[d, 0] - X[n0, 0], X[d, 1] - X[n0, 1], X[d, 2] - X[n0, 2]
    return s0 * s1 * s2 * (ax * (by * dz - bz * dy) + ay * (bz * dx - bx * dz) + az * (bx * dy - by * dx))


@intrinsic
def _bits(typingctx, x):
    """The IEEE-754 bits of a float64 as an int64 (no conversion)."""
    return nbtypes.int64(nbtypes.float64), lambda context, builder, sig, args: builder.bitcast(args[0], ir.IntType(64))


@intrinsic
def _from_bits(typingctx, i):
    """The float64 whose IEEE-754 bits are the int64 ``i``."""
    return nbtypes.float64(nbtypes.int64), lambda context, builder, sig, args: builder.bitcast(args[0], ir.DoubleType())


#: ``bits(x^(-1/3)) ~ _RCBRT - bits(x) / 3``: exact at powers of 8 for 1364 << 52 (the
#: exponent's bias times 4/3), lowered to halve the worst error over a period (6.8 %)
_RCBRT = 0x553EED916872B021


@nb.njit(cache=True, inline="always")
def _inv_cbrt_sq(h):
    """``h^(-2/3)`` for ``h > 0`` (normal): a guess from the bits, then four Newton steps for
    ``y = h^(-1/3)`` (relative errors 6.8e-2, 4.7e-3, 2.2e-5, 4.9e-10, 1e-15): no libm call and
    no division, ~2x cheaper than ``1 / cbrt(h * h)`` and as accurate to a few ulps."""
    y = _from_bits(_RCBRT - _bits(h) // 3)
    y = y * (4.0 - h * y * y * y) * (1.0 / 3.0)
    y = y * (4.0 - h * y * y * y) * (1.0 / 3.0)
    y = y * (4.0 - h * y * y * y) * (1.0 / 3.0)
    y = y * (4.0 - h * y * y * y) * (1.0 / 3.0)
    return y * y


@nb.njit(cache=True, inline="always")
def _escobar(F, D, dFx, dFy, dFz, dDx, dDy, dDz, diag, d2, hessian):
    """Escobar's corner functional ``F / (3 h(D)^(2/3))`` from the scaled edges' squared
    norm sum ``F`` and determinant ``D``, with its gradient and (``hessian``) Hessian from
    theirs (``D`` is affine in the node: no second derivative; ``F``'s Hessian is
    ``2 diag I``)."""
    r = np.sqrt(D * D + d2)
    h = max(0.5 * (D + r), 1e-300)
    hp = _inv_cbrt_sq(h)  # h^(-2/3)
    phi = hp * (1.0 / 3.0)
    ir = 1.0 / r
    dphi = -(2.0 / 9.0) * hp * ir
    g0 = phi * dFx + F * dphi * dDx
    g1 = phi * dFy + F * dphi * dDy
    g2 = phi * dFz + F * dphi * dDz
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    if hessian:
        ddphi = (2.0 / 9.0) * hp * ir * ir * ((2.0 / 3.0) + D * ir)
        dg = phi * 2.0 * diag
        w = F * ddphi
        h00 = dg + dphi * 2.0 * dFx * dDx + w * dDx * dDx
        h11 = dg + dphi * 2.0 * dFy * dDy + w * dDy * dDy
        h22 = dg + dphi * 2.0 * dFz * dDz + w * dDz * dDz
        h01 = dphi * (dFx * dDy + dDx * dFy) + w * dDx * dDy
        h02 = dphi * (dFx * dDz + dDx * dFz) + w * dDx * dDz
        h12 = dphi * (dFy * dDz + dDy * dFz) + w * dDy * dDz
    return F * phi, g0, g1, g2, h00, h01, h02, h11, h12, h22


def _escobar_sums_py(L, valence, d2, hessian):
    """Escobar's functional, gradient and (``hessian``) Hessian summed over the moved corners
    whose inputs :func:`node_eval` left in the frame's scratch columns.

    A loop of its own: each corner's functional is a long chain of dependent operations
    (square root, cube root, division) independent of the other corners', which this short
    loop lets the processor overlap."""
    f = g0 = g1 = g2 = 0.0
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    for r in range(valence):
        for q in range(4):
            k = 36 + 9 * q
            cf, c0, c1, c2, c00, c01, c02, c11, c12, c22 = _escobar(L[r, k], L[r, k + 1], L[r, k + 2], L[r, k + 3], L[r, k + 4], L[r, k + 5], L[r, k + 6], L[r, k + 7], L[r, k + 8], d2, hessian)
            f += cf
            g0, g1, g2 = g0 + c0, g1 + c1, g2 + c2
            h00, h01, h02, h11, h12, h22 = h00 + c00, h01 + c01, h02 + c02, h11 + c11, h12 + c12, h22 + c22
    return f, g0, g1, g2, h00, h01, h02, h11, h12, h22


_escobar_sums = nb.njit(cache=True)(_escobar_sums_py)
#: the same with fused multiply-adds and reordered sums (the only fast-math flags: no NaN or
#: infinity assumptions): ~30 % less time per Hessian evaluation of a light-pass node
#: (1.35-1.56 -> 0.92-1.05 us on the ICA). Only the light pass's Newton direction uses it:
#: untangling ends in a local optimum that rounding decides (a twisted boundary-layer band in
#: tests/test_optimize.py reached 0.324 exactly, 0.281 fused), while the light pass's steps
#: are judged by the scaled Jacobians alone, which this does not touch
_escobar_sums_fused = nb.njit(cache=True, fastmath={"contract", "reassoc"})(_variant(_escobar_sums_py, "_escobar_sums_fused"))

#: flags passed to :func:`node_eval` as plain booleans: numba types a ``True`` / ``False``
#: written in a call as a literal and compiles the callee once per combination (4 copies
#: of node_eval and 2 of each functional sum on a cold cache, ~3 s CPU); one copy branching
#: on them gives the same bits at the same speed (docs/speed.md, session 16)
_NO, _YES = np.bool_(False), np.bool_(True)


@nb.njit(cache=True)
def node_eval(L, ptr, inc, cq, v, z0, z1, z2, delta, hessian, want_f, want_q, buf, row, fused, floor, ratio_floor):
    """Functional and quality of node ``v`` displaced by ``z`` from where its frame ``L`` was
    taken (:func:`frame`), over the 4 corners of each incident hexahedron that it moves.

    The functional (``want_f``, with its Hessian when ``hessian``) uses the scaled edges
    (targets), the scaled Jacobians (``want_q``) the plain ones (a scaled Jacobian does not
    change when an edge is scaled); each hexahedron's other four corners come from the
    frame. With ``want_q``, the moved corners' values go to ``buf[row]`` (``row >= 0``; in
    the order of :func:`_moved`) or straight into ``cq`` (``row == -2``).

    ``fused`` (the light pass's Newton direction only, so always with ``hessian``) sums the
    functional with :func:`_escobar_sums_fused`.

    ``floor`` (a trial judged by its minimum, without the functional; ``-inf`` otherwise):
    the first corner whose scaled Jacobian falls below it ends the evaluation with ``qmin =
    -inf``, the trial's refusal known (the callers refuse any ``qmin`` below the start's);
    ``buf[row]`` is then incomplete, which only an accepted trial reads.

    ``ratio_floor`` (with ``want_q``; ``-inf``: off): an incident hexahedron whose Jacobian
    ratio (min det / max |det| over its corners) falls below the lesser of ``ratio_floor``
    and the incident hexahedra's least ratio where the frame was taken ends the evaluation
    the same way (a move may not taper an element: the corner scaled Jacobians do not see one
    edge shrinking). Like the scaled Jacobians' minimum, the neighbourhood's, not each
    element's: a per-element rule refuses every move that trades between two tapered
    elements, and then the pass cannot repair them.

    Returns ``(f, g0, g1, g2, H00, H01, H02, H11, H12, H22, qmin, qsum, below)``: the
    minimum and sum over the incident hexahedra of their scaled Jacobian (``want_q``), and the
    frame row whose corner fell below ``floor`` (-1: none; a hint for the node's next trial,
    :func:`.trials.row_below`).
    """
    f = g0 = g1 = g2 = 0.0
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    qmin = np.inf
    qsum = 0.0
    d2 = 4.0 * delta * delta
    guard = want_q and ratio_floor > -np.inf
    least = ratio_floor  # the incident hexahedra's least Jacobian ratio may not drop below this
    if guard:
        for r in range(ptr[v + 1] - ptr[v]):
            least = min(least, L[r, 74])
    for t in range(ptr[v], ptr[v + 1]):
        r = t - ptr[v]
        hmin = L[r, 35]
        S = L[r, 34]
        dlo, dhi = L[r, 72], L[r, 73]
        for q in range(4):
            if q == 0:  # the moving corner: its three edges u_a = p_a - z move
                u0x, u0y, u0z = L[r, 0] - z0, L[r, 1] - z1, L[r, 2] - z2
                u1x, u1y, u1z = L[r, 3] - z0, L[r, 4] - z1, L[r, 5] - z2
                u2x, u2y, u2z = L[r, 6] - z0, L[r, 7] - z1, L[r, 8] - z2
                m0, m1, m2 = u0x * u0x + u0y * u0y + u0z * u0z, u1x * u1x + u1y * u1y + u1z * u1z, u2x * u2x + u2y * u2y + u2z * u2z
                gx, gy, gz = L[r, 9], L[r, 10], L[r, 11]
                D = L[r, 12] + gx * z0 + gy * z1 + gz * z2
                N = m0 * m1 * m2
                s0, s1, s2 = L[r, 31], L[r, 32], L[r, 33]
                F = s0 * m0 + s1 * m1 + s2 * m2
                dFx = -2.0 * (s0 * u0x + s1 * u1x + s2 * u2x)
                dFy = -2.0 * (s0 * u0y + s1 * u1y + s2 * u2y)
                dFz = -2.0 * (s0 * u0z + s1 * u1z + s2 * u2z)
                diag = s0 + s1 + s2
            else:  # the neighbour along a: one edge w = z - p_a moves
                a = q - 1
                k = 13 + 6 * a
                wx, wy, wz = z0 - L[r, 3 * a], z1 - L[r, 3 * a + 1], z2 - L[r, 3 * a + 2]
                m = wx * wx + wy * wy + wz * wz
                gx, gy, gz = L[r, k], L[r, k + 1], L[r, k + 2]
                D = L[r, k + 3] + gx * z0 + gy * z1 + gz * z2
                N = m * L[r, k + 4]
                diag = L[r, 31 + a]
                F = diag * m + L[r, k + 5]
                dFx, dFy, dFz = 2.0 * diag * wx, 2.0 * diag * wy, 2.0 * diag * wz
            if want_q:
                sj = D / max(np.sqrt(N), 1e-300)
                if row >= 0:
                    buf[row, 4 * r + q] = sj
                elif row == -2:
                    e = inc[t] >> 3
                    l = inc[t] & 7
                    cq[e, l if q == 0 else l ^ (1 << (q - 1))] = sj
                if sj < floor:
                    return f, g0, g1, g2, h00, h01, h02, h11, h12, h22, -np.inf, qsum, r
                hmin = min(hmin, sj)
                dlo, dhi = min(dlo, D), max(dhi, abs(D))
            if want_f:  # the functional's inputs, for the second loop
                k = 36 + 9 * q
                L[r, k], L[r, k + 1], L[r, k + 2], L[r, k + 3], L[r, k + 4] = F, S * D, dFx, dFy, dFz
                L[r, k + 5], L[r, k + 6], L[r, k + 7], L[r, k + 8] = S * gx, S * gy, S * gz, diag
        if guard and dlo / max(dhi, 1e-300) < least:
            return f, g0, g1, g2, h00, h01, h02, h11, h12, h22, -np.inf, qsum, np.int64(-1)
        qsum += hmin
        qmin = min(qmin, hmin)
    if want_f and fused:  # only the Hessian's call fuses: a literal True keeps its contractions
        f, g0, g1, g2, h00, h01, h02, h11, h12, h22 = _escobar_sums_fused(L, ptr[v + 1] - ptr[v], d2, True)
    elif want_f:
        f, g0, g1, g2, h00, h01, h02, h11, h12, h22 = _escobar_sums(L, ptr[v + 1] - ptr[v], d2, hessian)
    return f, g0, g1, g2, h00, h01, h02, h11, h12, h22, qmin, qsum, np.int64(-1)


@nb.njit(cache=True)
def _worst_corner_direction(L, ptr, v):
    """Gradient, with respect to node ``v`` (at its frame's position), of the scaled Jacobian
    of the worst corner around it (the corner of smallest scaled Jacobian that ``v`` belongs
    to): the max-min ascent direction. With ``sj = D / prod |e_a|``:
    ``d sj = dD / prod |e_a| - sj sum_a d|e_a| / |e_a|`` (the volume's gradient alone can
    lengthen the edges faster than it adds volume)."""
    best = np.inf
    bx = by = bz = 0.0
    for t in range(ptr[v], ptr[v + 1]):
        r = t - ptr[v]
        for q in range(4):
            if q == 0:
                m0 = max(L[r, 0] ** 2 + L[r, 1] ** 2 + L[r, 2] ** 2, 1e-300)
                m1 = max(L[r, 3] ** 2 + L[r, 4] ** 2 + L[r, 5] ** 2, 1e-300)
                m2 = max(L[r, 6] ** 2 + L[r, 7] ** 2 + L[r, 8] ** 2, 1e-300)
                ln = np.sqrt(m0 * m1 * m2)
                sj = L[r, 12] / ln
                if sj < best:
                    best = sj
                    # the edges u_a = p_a - z shrink as z moves towards p_a
                    bx = L[r, 9] / ln + sj * (L[r, 0] / m0 + L[r, 3] / m1 + L[r, 6] / m2)
                    by = L[r, 10] / ln + sj * (L[r, 1] / m0 + L[r, 4] / m1 + L[r, 7] / m2)
                    bz = L[r, 11] / ln + sj * (L[r, 2] / m0 + L[r, 5] / m1 + L[r, 8] / m2)
            else:
                a = q - 1
                k = 13 + 6 * a
                m = max(L[r, 3 * a] ** 2 + L[r, 3 * a + 1] ** 2 + L[r, 3 * a + 2] ** 2, 1e-300)
                ln = max(np.sqrt(m * L[r, k + 4]), 1e-300)
                sj = L[r, k + 3] / ln
                if sj < best:
                    best = sj
                    # the edge w = z - p_a: d|w| / |w| = w . dz / m, with w = -p_a at z = 0
                    bx = L[r, k] / ln + sj * L[r, 3 * a] / m
                    by = L[r, k + 1] / ln + sj * L[r, 3 * a + 1] / m
                    bz = L[r, k + 2] / ln + sj * L[r, 3 * a + 2] / m
    return bx, by, bz


@nb.njit(cache=True)
def _acceptable(mode, f, qmin, qsum, f0, qmin0, qsum0):
    if f0 == np.inf:  # a max-min trial: the worst element must get better
        return qmin > qmin0 and (mode == UNTANGLE or qsum >= qsum0)
    if mode == ESCOBAR:
        return f < f0
    if mode == UNTANGLE:
        return f < f0 and qmin >= qmin0
    # smoothing a valid mesh: the quality itself decides (the functional only steers)
    return qmin >= qmin0 and qsum > qsum0


@nb.njit(cache=True)
def _trial_floor(mode, f0, qmin0):
    """The least corner scaled Jacobian a projected trial of a smoothing step can keep
    (:func:`_acceptable`: a max-min trial, ``f0 = inf``, must raise the minimum, a Newton
    trial keep it); ``-inf`` where the functional decides too."""
    if mode != SMOOTH:
        return -np.inf
    return np.nextafter(qmin0, np.inf) if f0 == np.inf else qmin0


@nb.njit(parallel=True, cache=True)
def corner_qualities(X, hexes, scale):
    """Scaled Jacobian of every corner ``(m, 8)``: the cache that :func:`frame` reads and every
    accepted move updates."""
    m = hexes.shape[0]
    out = np.empty((m, 8))
    for e in nb.prange(m):
        for c in range(8):
            e00, e01, e02, e10, e11, e12, e20, e21, e22 = _corner_edges(X, hexes, scale, np.int64(e), c)
            C0x, C0y, C0z, C1x, C1y, C1z, C2x, C2y, C2z = _cofactors(e00, e01, e02, e10, e11, e12, e20, e21, e22)
            D = e00 * C0x + e01 * C0y + e02 * C0z
            n0 = e00 * e00 + e01 * e01 + e02 * e02
            n1 = e10 * e10 + e11 * e11 + e12 * e12
            n2 = e20 * e20 + e21 * e21 + e22 * e22
            out[e, c] = D / max(np.sqrt(n0 * n1 * n2), 1e-300)
    return out


@nb.njit(cache=True)
def _moved(X, hexes, ptr, inc, cq, v, L, y0, y1, y2, dirty, buf, row, least):
    """Move ``v`` (at its frame's position) to ``y``: its corners' cached qualities follow
    (from ``buf[row]``, the values :func:`node_eval` left there at this position, or
    recomputed when ``row < 0``) and its neighbours are dirty when it moved at least
    ``least`` (a converged node's tiny moves change its neighbours' optimum by less than
    they gain from another try; callers pass 0 for a move that raised the worst element
    around the node, which may go on)."""
    z0, z1, z2 = y0 - X[v, 0], y1 - X[v, 1], y2 - X[v, 2]
    step = np.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
    X[v, 0], X[v, 1], X[v, 2] = y0, y1, y2
    if row < 0:
        node_eval(L, ptr, inc, cq, v, z0, z1, z2, 0.0, _NO, _NO, _YES, buf, np.int64(-2), _NO, -np.inf, -np.inf)
    else:
        for t in range(ptr[v], ptr[v + 1]):
            e = inc[t] >> 3
            l = inc[t] & 7
            for q in range(4):
                cq[e, l if q == 0 else l ^ (1 << (q - 1))] = buf[row, 4 * (t - ptr[v]) + q]
    if step >= least:
        _mark(hexes, ptr, inc, v, dirty)


@nb.njit(cache=True)
def _chunk(n, chunks, i):
    """Nodes ``[lo, hi)`` of chunk ``i`` of ``chunks`` (one frame buffer each)."""
    return i * n // chunks, (i + 1) * n // chunks


@nb.njit(cache=True)
def _step_node(X, hexes, scale, ptr, inc, cq, j, v, kind, normal, step_cap, delta, mode, goal, trial, state, dirty, buf, tol, L, ratio_floor, over_relax):
    """One Newton step with backtracking for node ``v`` (row ``j`` of its colour), else a
    max-min climb; see :func:`_sweep_colour`."""
    frame(X, hexes, scale, ptr, inc, cq, v, L, mode == SMOOTH and ratio_floor > -np.inf)
    on_wall = kind[v] == WALL or kind[v] == OFFSET
    # the start's quality from the frame, as every trial's: the cache's values of the moved
    # corners (computed in other frames) differ in the last bits, enough to refuse the short
    # steps that climb the worst element
    f0, g0, g1, g2, h00, h01, h02, h11, h12, h22, qmin0, qsum0, _ = node_eval(L, ptr, inc, cq, v, 0.0, 0.0, 0.0, delta, _YES, _YES, _YES, buf, np.int64(j), mode == SMOOTH, -np.inf, -np.inf)
    if mode == ESCOBAR and not on_wall:
        qmin0, qsum0 = np.inf, 0.0
    state[j, 0], state[j, 1], state[j, 2] = f0, qmin0, qsum0
    d0, d1, d2 = _newton_direction(g0, g1, g2, h00, h01, h02, h11, h12, h22, kind[v], normal[v, 0], normal[v, 1], normal[v, 2])
    length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    # a stationary point of the functional (a symmetric mesh) takes no Newton step but
    # may still climb below
    newton = length > 0.0 and np.isfinite(length)
    if newton and length > step_cap[v]:
        d0, d1, d2 = d0 * step_cap[v] / length, d1 * step_cap[v] / length, d2 * step_cap[v] / length
    # smoothing is judged by the quality alone (no functional value needed), untangling
    # by the functional (and wall nodes again after their projection)
    smooth = mode == SMOOTH
    judge = mode != ESCOBAR and not on_wall
    t = over_relax if smooth and not on_wall else 1.0
    guarded = smooth and ratio_floor > -np.inf  # the taper guard (the default): trial_quality_guarded
    least = least_ratio(L, ptr[v + 1] - ptr[v], ratio_floor) if guarded else -np.inf
    hint = -1  # the frame row whose corner refused the last trial: checked first (trials.row_below)
    # a light-pass trial is refused as soon as its sum of minima cannot reach the start's
    # (buf[j] holds the start's moved corners, read by an accepted trial's move only)
    gap_floor = order_rows(L, ptr[v + 1] - ptr[v], buf[j], qsum0) if smooth and not on_wall else 0.0
    for _ in range((SMOOTH_TRIALS + (1 if t > 1.0 else 0) if smooth else 8) if newton else 0):
        z0, z1, z2 = t * d0, t * d1, t * d2
        if on_wall and smooth:  # judged after the projection
            trial[j, 0], trial[j, 1], trial[j, 2] = X[v, 0] + z0, X[v, 1] + z1, X[v, 2] + z2
            state[j, 3] = 1.0
            return
        if smooth and hint >= 0 and row_below(L, hint, z0, z1, z2, qmin0):
            t = 1.0 if t > 1.0 else 0.5 * t
            continue
        if smooth:
            qmin, qsum, below = trial_quality_ordered(L, ptr, v, z0, z1, z2, buf, np.int64(j), qmin0, least, guarded, gap_floor)
            r = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, qmin, qsum, below)
        else:
            # an untangling trial judged by its minimum too is refused at its first corner
            # below the start's minimum, before the functional (the same decision)
            r = node_eval(L, ptr, inc, cq, v, z0, z1, z2, delta, _NO, not smooth, judge or smooth, buf, np.int64(j), _NO, qmin0 if smooth or (mode == UNTANGLE and judge) else -np.inf, ratio_floor if smooth else -np.inf)
        if r[12] >= 0:
            hint = r[12]
        if (r[0] < f0) if not smooth else _acceptable(mode, r[0], r[10], r[11], f0, qmin0, qsum0):
            if on_wall:  # judged again after the projection
                trial[j, 0], trial[j, 1], trial[j, 2] = X[v, 0] + z0, X[v, 1] + z1, X[v, 2] + z2
                state[j, 3] = 1.0
                return
            if mode != UNTANGLE or _acceptable(mode, r[0], r[10], r[11], f0, qmin0, qsum0):
                _moved(X, hexes, ptr, inc, cq, v, L, X[v, 0] + z0, X[v, 1] + z1, X[v, 2] + z2, dirty, buf, np.int64(j) if judge or smooth else np.int64(-1), 0.0 if r[10] > qmin0 else tol * step_cap[v])
                state[j, 3] = 1.0
                return
        t = 1.0 if t > 1.0 else 0.5 * t
    if qmin0 < goal and mode != ESCOBAR:
        # no Newton step helps: climb the worst corner instead (max-min), judged by the
        # incident elements' minimum scaled Jacobian alone
        d0, d1, d2 = _worst_corner_direction(L, ptr, v)
        if kind[v] != FREE:
            dn = d0 * normal[v, 0] + d1 * normal[v, 1] + d2 * normal[v, 2]
            d0, d1, d2 = d0 - dn * normal[v, 0], d1 - dn * normal[v, 1], d2 - dn * normal[v, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if length == 0.0 or not np.isfinite(length):
            return
        d0, d1, d2 = d0 * step_cap[v] / length, d1 * step_cap[v] / length, d2 * step_cap[v] / length
        t = 0.25
        climb_floor = np.nextafter(qmin0, np.inf)  # a climb must raise the minimum: sj <= qmin0 refuses
        for _ in range(CLIMB_TRIALS):
            z0, z1, z2 = t * d0, t * d1, t * d2
            if on_wall:
                trial[j, 0], trial[j, 1], trial[j, 2] = X[v, 0] + z0, X[v, 1] + z1, X[v, 2] + z2
                state[j, 0] = np.inf  # the functional is not asked for
                state[j, 3] = 1.0
                return
            if hint >= 0 and row_below(L, hint, z0, z1, z2, climb_floor):
                t *= 0.5
                continue
            if smooth:  # a climb may not lower the sum either: refused once it cannot reach it
                qmin, qsum, below = trial_quality_ordered(L, ptr, v, z0, z1, z2, buf, np.int64(j), climb_floor, least, guarded, gap_floor)
            elif not guarded:
                qmin, qsum, below = trial_quality(L, ptr, v, z0, z1, z2, buf, np.int64(j), climb_floor)
            else:
                qmin, qsum, below = trial_quality_guarded(L, ptr, v, z0, z1, z2, buf, np.int64(j), climb_floor, least)
            if below >= 0:
                hint = below
            if _acceptable(mode, np.inf, qmin, qsum, np.inf, qmin0, qsum0):
                # a climb raises a worst element: however short, the neighbours try again
                _moved(X, hexes, ptr, inc, cq, v, L, X[v, 0] + z0, X[v, 1] + z1, X[v, 2] + z2, dirty, buf, np.int64(j), 0.0)
                state[j, 3] = 1.0
                return
            t *= 0.5


def _sweep_colour(X, hexes, scale, ptr, inc, cq, nodes, kind, normal, step_cap, delta, mode, goal, trial, state, dirty, buf, tol, ratio_floor, over_relax):
    """One Newton step with backtracking for every node of one colour (no two share a hexahedron).

    Free and plane nodes are updated in ``X``; wall nodes get their tangential trial
    position in ``trial`` (to be projected onto the wall and checked by :func:`accept_trials`),
    with their start values ``(f, qmin, qsum)`` in ``state``. ``cq`` holds the corner scaled
    Jacobians of the stage's hexahedra and follows every move. A move shorter than ``tol``
    times the node's step cap does not make its neighbours dirty. Smoothing trials
    (``mode == SMOOTH``) must also keep every incident hexahedron's Jacobian ratio at or above
    the lesser of ``ratio_floor`` and the least ratio of the node's incident hexahedra before
    the step (a neighbourhood rule, like the scaled Jacobian's) (``-inf``: no such guard; see
    :func:`node_eval`). Returns nothing;
    ``state[:, 3]`` is 1 where a node moved (or has a trial), else 0.
    """
    n = len(nodes)
    chunks = min(n, CHUNKS)
    frames = np.empty((chunks, buf.shape[1] // 4, NL))
    for i in nb.prange(chunks):
        lo, hi = _chunk(n, chunks, i)
        for j in range(lo, hi):
            ahead(X, hexes, scale, cq, ptr, inc, nodes, dirty, True, j, hi)
            v = nodes[j]
            state[j, 3] = 0.0
            trial[j, 0], trial[j, 1], trial[j, 2] = X[v, 0], X[v, 1], X[v, 2]
            if not dirty[v]:  # nothing around it moved since it last failed to improve
                state[j, 0] = -1.0
                continue
            dirty[v] = False
            _step_node(X, hexes, scale, ptr, inc, cq, j, v, kind, normal, step_cap, delta, mode, goal, trial, state, dirty, buf, tol, frames[i], ratio_floor, over_relax)


def _accept_trials(X, hexes, scale, ptr, inc, cq, nodes, projected, delta, mode, state, dirty, buf, step_cap, tol, ratio_floor):
    """Move wall nodes to their projected trial positions where that still improves them
    (the functional decreases and, for untangling, no incident element gets worse than
    the worst before; for smoothing, their minimum and sum of scaled Jacobians do not drop)."""
    n = len(nodes)
    chunks = min(n, CHUNKS)
    frames = np.empty((chunks, buf.shape[1] // 4, NL))
    for i in nb.prange(chunks):
        lo, hi = _chunk(n, chunks, i)
        L = frames[i]
        for j in range(lo, hi):
            ahead(X, hexes, scale, cq, ptr, inc, nodes, dirty, False, j, hi)
            v = nodes[j]
            frame(X, hexes, scale, ptr, inc, cq, v, L, mode == SMOOTH and ratio_floor > -np.inf)
            z0, z1, z2 = projected[j, 0] - X[v, 0], projected[j, 1] - X[v, 1], projected[j, 2] - X[v, 2]
            r = node_eval(L, ptr, inc, cq, v, z0, z1, z2, delta, _NO, mode != SMOOTH, _YES, buf, np.int64(j), _NO, _trial_floor(mode, state[j, 0], state[j, 1]), ratio_floor if mode == SMOOTH else -np.inf)
            if _acceptable(mode, r[0], r[10], r[11], state[j, 0], state[j, 1], state[j, 2]):
                _moved(X, hexes, ptr, inc, cq, v, L, projected[j, 0], projected[j, 1], projected[j, 2], dirty, buf, np.int64(j), 0.0 if state[j, 0] == np.inf or r[10] > state[j, 1] else tol * step_cap[v])
            else:
                state[j, 3] = 0.0
                if mode == SMOOTH:
                    # a wall node gets one trial per sweep (its projection is batched):
                    # refused, it tries again next sweep with half the step
                    step_cap[v] *= 0.5
                    dirty[v] = True


#: parallel versions for large colours and serial ones for small colours (a parallel launch
#: costs more than a few hundred node updates, and much more on a loaded machine)
sweep_colour_parallel = nb.njit(parallel=True, cache=True)(_variant(_sweep_colour, "sweep_colour_parallel"))
sweep_colour_serial = nb.njit(cache=True)(_variant(_sweep_colour, "sweep_colour_serial"))
accept_trials_parallel = nb.njit(parallel=True, cache=True)(_variant(_accept_trials, "accept_trials_parallel"))
accept_trials_serial = nb.njit(cache=True)(_variant(_accept_trials, "accept_trials_serial"))
#: colours with fewer nodes than this run serially
PARALLEL_FROM = 4096


def warm_up() -> None:
    """Compile (or load) the kernels ``optimize`` calls, serial and parallel, on a single
    hexahedron with every node fixed, with the argument types ``optimize`` passes: ``vmesh
    compile`` calls it (its small tube only needs the serial variants), and so does the
    background compile of a first run (``vmesh compile --optimiser``)."""
    X = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], np.float64)
    hexes = np.arange(8, dtype=np.int64).reshape(1, 8)
    scale = target_scales(X, hexes, 1e-9)
    ptr, inc = incidence(hexes, 8)
    cq = corner_qualities(X, hexes, scale)
    nodes = np.arange(8, dtype=np.int64)
    colour_nodes(hexes, ptr, inc, nodes, 8)
    grow_nodes(hexes, ptr, inc, np.zeros(8, np.bool_))
    step_caps(X, hexes, ptr, inc, nodes, 8, 0.5)
    from .objective import escobar_sum

    escobar_sum(X, hexes, np.ones((1, 8, 3)), 1e-3, np.zeros((8, 3)))  # the L-BFGS untangler's objective
    kind, normal, caps = np.full(8, FIXED, np.int64), np.zeros((8, 3)), np.zeros(8)
    for sweep, accept in ((sweep_colour_serial, accept_trials_serial), (sweep_colour_parallel, accept_trials_parallel)):
        trial, state, dirty, buf = np.zeros((8, 3)), np.zeros((8, 4)), np.zeros(8, np.bool_), np.zeros((8, 32))
        sweep(X, hexes, scale, ptr, inc, cq, nodes, kind, normal, caps, 1e-3, SMOOTH, 0.5, trial, state, dirty, buf, 0.0, 0.3, 1.0)
        accept(X, hexes, scale, ptr, inc, cq, nodes, trial, 1e-3, SMOOTH, state, dirty, buf, caps, 0.0, 0.3)
    # the max-min pass's last: every run needs the sweeps, only runs left below smooth_below
    # these, and a first run's optimiser may start while the background compile is still here
    from . import kernels_worst as KW

    # with the taper guard (on by default since session 23) the worst pass also needs ratio_rows
    for corners, minima, rows in ((KW._worst_corners_serial, KW._trial_minima_serial, KW._ratio_rows_serial),
                                  (KW._worst_corners_parallel, KW._trial_minima_parallel, KW._ratio_rows_parallel)):
        corners(X, hexes, ptr, inc, nodes)
        minima(X, hexes, ptr, inc, nodes, np.ascontiguousarray(X[:, None]), 0.3)
        rows(X, hexes, ptr, inc, nodes, 0.3)
