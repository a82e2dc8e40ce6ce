"""The L-BFGS untangler's objective, compiled: Escobar's corner functional summed over a
region's hexahedra with its gradient (:func:`vmesh.geometry.untangle._objective`).

Kept apart from :mod:`.kernels` (the local optimiser's node updates), whose corner
functional it writes out again with its own arithmetic (see the note in :func:`escobar_sum`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .kernels import _cofactors


@nb.njit(cache=True)
def escobar_sum(X, hexes, scale, delta, grad):
    """Sum of Escobar's corner functional over every corner of ``hexes`` and its gradient
    with respect to every node (into ``grad``, zeroed here): the objective of the L-BFGS
    untangler (:func:`vmesh.geometry.untangle._objective`, whose numpy form it replaces:
    one pass over the corners instead of some forty temporaries of the region's size).

    Parameters
    ----------
    X : (n, 3) float
    hexes : (m, 8) int, tensor corner order
    scale : (m, 8, 3) float
        Per corner and axis, 1 / the target length of the corner's edge along +axis.
    delta : float
        Regularisation of the determinant.
    grad : (n, 3) float
        Output.

    Returns
    -------
    float
        The functional's sum.
    """
    grad[:] = 0.0
    d2 = 4.0 * delta * delta
    total = 0.0
    for e in range(hexes.shape[0]):
        for c in range(8):
            # the corner's edges along +i, +j, +k: the hexahedron's edges through it,
            # oriented from the 0 to the 1 end whatever the corner's own bit is
            a0, a1 = hexes[e, c & 6], hexes[e, c | 1]
            b0, b1 = hexes[e, c & 5], hexes[e, c | 2]
            c0, c1 = hexes[e, c & 3], hexes[e, c | 4]
            s0, s1, s2 = scale[e, c, 0], scale[e, c, 1], scale[e, c, 2]
            e00, e01, e02 = (X[a1, 0] - X[a0, 0]) * s0, (X[a1, 1] - X[a0, 1]) * s0, (X[a1, 2] - X[a0, 2]) * s0
            e10, e11, e12 = (X[b1, 0] - X[b0, 0]) * s1, (X[b1, 1] - X[b0, 1]) * s1, (X[b1, 2] - X[b0, 2]) * s1
            e20, e21, e22 = (X[c1, 0] - X[c0, 0]) * s2, (X[c1, 1] - X[c0, 1]) * s2, (X[c1, 2] - X[c0, 2]) * s2
            C0x, C0y, C0z, C1x, C1y, C1z, C2x, C2y, C2z = _cofactors(e00, e01, e02, e10, e11, e12, e20, e21, e22)
            D = e00 * C0x + e01 * C0y + e02 * C0z
            F = e00 * e00 + e01 * e01 + e02 * e02 + e10 * e10 + e11 * e11 + e12 * e12 + e20 * e20 + e21 * e21 + e22 * e22
            # duplicates: kernels._escobar's corner functional, written out with libm's pow and the edge form
            # of the gradient: the L-BFGS untangler's end point depends on the objective's last bits
            # (with _escobar's arithmetic, 2026-12-04: sv_rpa given 0.347 -> 0.242, coarctation 0.497 -> 0.492)
            r = np.sqrt(D * D + d2)
            h = max(0.5 * (D + r), 1e-300)
            hp = h ** (-2.0 / 3.0)
            total += F * hp * (1.0 / 3.0)
            a = (2.0 / 3.0) * hp
            b = (2.0 / 9.0) * F * hp / r
            # d f / d edge = a e - b (cofactor row of that edge), times the edge's scale
            # duplicates: the three edges' scatters are unrolled on purpose (scalars in registers; a helper taking
            # the gradient array per edge costs the inlined kernel its speed)
            gx, gy, gz = (a * e00 - b * C0x) * s0, (a * e01 - b * C0y) * s0, (a * e02 - b * C0z) * s0
            grad[a1, 0] += gx
            grad[a1, 1] += gy
            grad[a1, 2] += gz
            grad[a0, 0] -= gx
            grad[a0, 1] -= gy
            grad[a0, 2] -= gz
            gx, gy, gz = (a * e10 - b * C1x) * s1, (a * e11 - b * C1y) * s1, (a * e12 - b * C1z) * s1
            grad[b1, 0] += gx
            grad[b1, 1] += gy
            grad[b1, 2] += gz
            grad[b0, 0] -= gx
            grad[b0, 1] -= gy
            grad[b0, 2] -= gz
            gx, gy, gz = (a * e20 - b * C2x) * s2, (a * e21 - b * C2y) * s2, (a * e22 - b * C2z) * s2
            grad[c1, 0] += gx
            grad[c1, 1] += gy
            grad[c1, 2] += gz
            grad[c0, 0] -= gx
            grad[c0, 1] -= gy
            grad[c0, 2] -= gz
    return total
