"""Trials of the light pass judged by the scaled Jacobians alone (:mod:`.kernels`).

A light-pass update evaluates its frame, its Newton direction and ~4 trials (on the ICA at
vascularmd's resolution); most refused trials keep the minimum but not the sum of minima and
are evaluated in full. These kernels evaluate such trials with exactly the arithmetic of
:func:`.kernels.node_eval` (so the same values and decisions) without the functional's
inputs, and decide a refusal from one frame row (docs/speed.md, *Seventeenth round*).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(inline="always", cache=True)
def _sj_own(L, r, z0, z1, z2):
    """Scaled Jacobian of frame row ``r``'s corner at the node moved to ``z`` (:func:`.kernels.node_eval`'s arithmetic)."""
    return _sj_det_own(L, r, z0, z1, z2)[0]


@nb.njit(inline="always", cache=True)
def _sj_adjacent(L, r, a, z0, z1, z2):
    """Scaled Jacobian of frame row ``r``'s corner at its edge neighbour ``a`` (0-2) with the node at ``z``."""
    return _sj_det_adjacent(L, r, a, z0, z1, z2)[0]


@nb.njit(inline="always", cache=True)
def _sj_det_own(L, r, z0, z1, z2):
    """:func:`_sj_own` and the corner's (plain) determinant ``D``."""
    u0x, u0y, u0z = L[r, 0] - z0, L[r, 1] - z1, L[r, 2] - z2
    u1x, u1y, u1z = L[r, 3] - z0, L[r, 4] - z1, L[r, 5] - z2
    u2x, u2y, u2z = L[r, 6] - z0, L[r, 7] - z1, L[r, 8] - z2
    m0, m1, m2 = u0x * u0x + u0y * u0y + u0z * u0z, u1x * u1x + u1y * u1y + u1z * u1z, u2x * u2x + u2y * u2y + u2z * u2z
    D = L[r, 12] + L[r, 9] * z0 + L[r, 10] * z1 + L[r, 11] * z2
    return D / max(np.sqrt(m0 * m1 * m2), 1e-300), D


@nb.njit(inline="always", cache=True)
def _sj_det_adjacent(L, r, a, z0, z1, z2):
    """:func:`_sj_adjacent` and the corner's (plain) determinant ``D``."""
    k = 13 + 6 * a
    wx, wy, wz = z0 - L[r, 3 * a], z1 - L[r, 3 * a + 1], z2 - L[r, 3 * a + 2]
    m = wx * wx + wy * wy + wz * wz
    D = L[r, k + 3] + L[r, k] * z0 + L[r, k + 1] * z1 + L[r, k + 2] * z2
    return D / max(np.sqrt(m * L[r, k + 4]), 1e-300), D


@nb.njit(cache=True)
def row_below(L, r, z0, z1, z2, floor):
    """Whether one of the 4 corners that node displacement ``z`` moves in frame row ``r``
    (:func:`.kernels.frame`) has a scaled Jacobian below ``floor``: the same arithmetic as
    :func:`.kernels.node_eval`'s, so the same values and decisions.

    A trial judged by its minimum is refused at its first corner below the start's minimum,
    and the corner that refused a node's trial usually refuses its next, shorter one too: the
    node's trials check that row first (:func:`.kernels._step_node`) instead of reaching it after up
    to 7 other hexahedra. Only a refusal is decided here; a trial that passes is evaluated
    whole by :func:`.kernels.node_eval`."""
    if _sj_own(L, r, z0, z1, z2) < floor:
        return True
    for a in range(3):
        if _sj_adjacent(L, r, a, z0, z1, z2) < floor:
            return True
    return False


@nb.njit(cache=True)
def trial_quality(L, ptr, v, z0, z1, z2, buf, row, floor):
    """:func:`.kernels.node_eval` of a trial judged by the scaled Jacobians alone (``want_q`` only, no
    functional, no Jacobian-ratio guard): the same arithmetic in the same order, so the same
    values, without the functional's inputs that such a trial does not read (most of a
    light-pass update's time is its trials: ~4 per update on the ICA).

    Returns ``(qmin, qsum, below)`` as :func:`.kernels.node_eval`'s last three values; the moved
    corners' scaled Jacobians go to ``buf[row]``."""
    qmin = np.inf
    qsum = 0.0
    for t in range(ptr[v], ptr[v + 1]):
        r = t - ptr[v]
        hmin = L[r, 35]
        sj = _sj_own(L, r, z0, z1, z2)
        buf[row, 4 * r] = sj
        if sj < floor:
            return -np.inf, qsum, r
        hmin = min(hmin, sj)
        for a in range(3):
            sj = _sj_adjacent(L, r, a, z0, z1, z2)
            buf[row, 4 * r + 1 + a] = sj
            if sj < floor:
                return -np.inf, qsum, r
            hmin = min(hmin, sj)
        qsum += hmin
        qmin = min(qmin, hmin)
    return qmin, qsum, np.int64(-1)


@nb.njit(cache=True)
def least_ratio(L, valence, ratio_floor):
    """The Jacobian ratio a guarded trial may not go below: the lesser of ``ratio_floor`` and
    the least ratio of the node's incident hexahedra where its frame was taken (column 74 of
    :func:`.kernels.frame`; :func:`.kernels.node_eval` takes the same minimum in every call)."""
    least = ratio_floor
    for r in range(valence):
        least = min(least, L[r, 74])
    return least


@nb.njit(cache=True)
def trial_quality_guarded(L, ptr, v, z0, z1, z2, buf, row, floor, least):
    """:func:`trial_quality` with the taper guard (on by default): :func:`.kernels.node_eval`
    with ``want_q`` and a ``ratio_floor`` but no functional, the same arithmetic in the same
    order, so the same values and decisions. A hexahedron whose Jacobian ratio (least
    determinant over largest magnitude of its 8 corners; the 4 the node does not move come
    from the frame, columns 72-73) falls below ``least`` (:func:`least_ratio`) refuses the
    trial like a corner below ``floor``, without a row hint.

    Returns ``(qmin, qsum, below)`` as :func:`trial_quality`."""
    qmin = np.inf
    qsum = 0.0
    for t in range(ptr[v], ptr[v + 1]):
        r = t - ptr[v]
        hmin = L[r, 35]
        dlo, dhi = L[r, 72], L[r, 73]
        sj, D = _sj_det_own(L, r, z0, z1, z2)
        buf[row, 4 * r] = sj
        if sj < floor:
            return -np.inf, qsum, r
        hmin = min(hmin, sj)
        dlo, dhi = min(dlo, D), max(dhi, abs(D))
        for a in range(3):
            sj, D = _sj_det_adjacent(L, r, a, z0, z1, z2)
            buf[row, 4 * r + 1 + a] = sj
            if sj < floor:
                return -np.inf, qsum, r
            hmin = min(hmin, sj)
            dlo, dhi = min(dlo, D), max(dhi, abs(D))
        if dlo / max(dhi, 1e-300) < least:
            return -np.inf, qsum, np.int64(-1)
        qsum += hmin
        qmin = min(qmin, hmin)
    return qmin, qsum, np.int64(-1)


#: a trial is refused early (:func:`trial_quality_ordered`) only where its sum of minima's
#: upper bound is below the start's by more than this: the bound and the trial's sum are
#: rounded in another order (each within ~1e-13 of its exact value for |SJ| <= 1 and a few
#: dozen hexahedra), so an early refusal is one the whole evaluation would also make
SUM_MARGIN = 1e-9
#: frame columns (:func:`.kernels.frame`'s scratch past its own): the rows in the order a
#: light-pass trial evaluates them (as floats), and each row's minimum in the last trial
ORDER, HMIN = 75, 76


@nb.njit(cache=True)
def order_rows(L, valence, start, qsum0):
    """Order the frame's rows for :func:`trial_quality_ordered` and return its ``gap_floor``.

    A hexahedron's minimum is at most that of the four corners the node does not move
    (column 35), whatever the trial; a row whose start minimum ``min(L[r, 35], start's 4
    moved corners)`` already is that value cannot gain, only lose. The rows that can gain go
    first (``L[:, ORDER]``), so that once they are evaluated the trial's sum of minima is
    bounded by what it has so far plus the others' column 35: a trial that must raise the
    sum (a Newton step) or keep it (a climb) is refused there, without the rows that cannot
    gain (most refused light-pass trials keep the minimum but not the sum, docs/speed.md,
    *Seventeenth round*).

    ``start`` holds the start's moved corners (4 per row, as :func:`trial_quality`'s ``buf``
    row). Returns the least sum over the rows evaluated so far of ``hmin - L[r, 35]`` a trial
    can still be kept with: ``qsum0`` less every row's column 35 and :data:`SUM_MARGIN`."""
    k = 0
    for gains in (True, False):
        for r in range(valence):
            low = min(min(start[4 * r], start[4 * r + 1]), min(start[4 * r + 2], start[4 * r + 3]))
            if (low < L[r, 35]) == gains:
                L[k, ORDER] = r
                k += 1
    total = 0.0
    for r in range(valence):
        total += L[r, 35]
    return qsum0 - total - SUM_MARGIN


@nb.njit(cache=True)
def trial_quality_ordered(L, ptr, v, z0, z1, z2, buf, row, floor, least, guarded, gap_floor):
    """:func:`trial_quality` (``guarded``: :func:`trial_quality_guarded` with ``least``) of a
    light-pass trial, its rows in the order of :func:`order_rows`, refused (``qmin = -inf``,
    ``below = -1``) as soon as its sum of minima cannot reach the start's (``gap_floor``).

    Each row's values are those of the row-order functions (the same arithmetic), the sum of
    minima is taken in row order at the end, so an accepted trial gives the same ``qmin``,
    ``qsum`` and ``buf[row]`` bit for bit, and a refused one is refused by them too; only the
    refusing row (``below``: a hint) may differ."""
    n = ptr[v + 1] - ptr[v]
    gap = 0.0
    for i in range(n):
        r = np.int64(L[i, ORDER])
        # duplicates: the row evaluation of trial_quality_guarded, written out in each kernel:
        # the early returns leave the loop from inside the row (a helper would return a status)
        hmin = L[r, 35]
        dlo, dhi = L[r, 72], L[r, 73]
        sj, D = _sj_det_own(L, r, z0, z1, z2)
        buf[row, 4 * r] = sj
        if sj < floor:
            return -np.inf, 0.0, r
        hmin = min(hmin, sj)
        dlo, dhi = min(dlo, D), max(dhi, abs(D))
        for a in range(3):
            sj, D = _sj_det_adjacent(L, r, a, z0, z1, z2)
            buf[row, 4 * r + 1 + a] = sj
            if sj < floor:
                return -np.inf, 0.0, r
            hmin = min(hmin, sj)
            dlo, dhi = min(dlo, D), max(dhi, abs(D))
        if guarded and dlo / max(dhi, 1e-300) < least:
            return -np.inf, 0.0, np.int64(-1)
        L[r, HMIN] = hmin
        gap += hmin - L[r, 35]
        if gap < gap_floor:
            return -np.inf, 0.0, np.int64(-1)
    qmin = np.inf
    qsum = 0.0
    for r in range(n):
        qsum += L[r, HMIN]
        qmin = min(qmin, L[r, HMIN])
    return qmin, qsum, np.int64(-1)
