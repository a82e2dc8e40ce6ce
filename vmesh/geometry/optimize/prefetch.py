"""Software prefetch for the optimiser's colour passes (:mod:`.kernels`).

A colour pass visits every node of one colour, ~1/16 of the stage's nodes spread over all of
it, so each node update starts with cache misses on its hexahedra's rows and their nodes'
points (the frame costs ~3x more in colour order than in node order, docs/speed.md: the
nodes of one colour are far apart in memory). Asking for the next nodes' data while the current node computes hides most of that
latency; the results are unchanged (a prefetch only moves data into the caches).
"""

from __future__ import annotations

import numba as nb
from llvmlite import ir
from numba.core import cgutils
from numba.core import types as nbtypes
from numba.extending import intrinsic

#: how far ahead (in the colour's node list) the hexahedron rows and the points are asked for:
#: a point's address is read from a hexahedron row, which must have arrived first
ROWS_AHEAD, POINTS_AHEAD = 4, 2
#: and the incidence of a node (its hexahedra's numbers) before that
INC_AHEAD = 8
# The three distances were measured on a light pass: longer ones gave no gain. Results do
# not depend on them: a prefetch is a hint only and changes no value read.


#: the intrinsic's name is mangled on its pointer type as llvmlite names it (``p0i8``); LLVM's
#: auto-upgrade renames it where pointers are opaque (``p0``)
_NAME = "llvm.prefetch." + ir.IntType(8).as_pointer().intrinsic_name


@intrinsic
def _prefetch(typingctx, addr):
    """``llvm.prefetch`` of the byte at address ``addr`` (read, keep in all cache levels)."""

    def codegen(context, builder, sig, args):
        i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), _NAME)
        builder.call(fn, [builder.inttoptr(args[0], i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return nbtypes.void(nbtypes.uintp), codegen


@nb.njit(cache=True, inline="always")
def _rows(hexes, scale, cq, ptr, inc, v):
    """Ask for the rows of ``hexes``, ``scale`` and ``cq`` of node ``v``'s hexahedra."""
    h, s, q = hexes.ctypes.data, scale.ctypes.data, cq.ctypes.data
    hs, ss, qs = hexes.strides[0], scale.strides[0], cq.strides[0]
    for t in range(ptr[v], ptr[v + 1]):
        e = inc[t] >> 3
        _prefetch(h + e * hs)
        _prefetch(h + e * hs + hs - 1)  # a row may straddle two cache lines
        _prefetch(s + e * ss)
        _prefetch(q + e * qs)
        _prefetch(q + e * qs + qs - 1)


@nb.njit(cache=True, inline="always")
def _points(X, hexes, ptr, inc, v):
    """Ask for the points of the nodes of node ``v``'s hexahedra."""
    x, xs = X.ctypes.data, X.strides[0]
    for t in range(ptr[v], ptr[v + 1]):
        e = inc[t] >> 3
        for c in range(8):
            _prefetch(x + hexes[e, c] * xs)


@nb.njit(cache=True, inline="always")
def ahead(X, hexes, scale, cq, ptr, inc, nodes, dirty, only_dirty, j, hi):
    """Before node ``nodes[j]`` is updated, ask for what the updates of the next nodes will read.

    Parameters
    ----------
    X : (n, 3) float
        Node positions.
    hexes : (m, 8) int
        The stage's hexahedra.
    scale : (m, 3) float
        Per hexahedron, the inverse target edge length along each axis.
    cq : (m, 8) float
        Per hexahedron, its corners' scaled Jacobians.
    ptr, inc : (n + 1,) int, (k,) int
        Node-to-hexahedron incidence (CSR; ``inc[t] >> 3`` is the hexahedron).
    nodes : (c,) int
        The colour's nodes, in update order.
    dirty : (n,) bool
        Nodes with something to do.
    only_dirty : bool
        Skip nodes that are not ``dirty``.
    j : int
        Position in ``nodes`` of the node about to be updated.
    hi : int
        End of the caller's chunk of ``nodes``: nothing past it is asked for.

    Notes
    -----
    Asks for the incidence of ``nodes[j + INC_AHEAD]``, the rows of ``nodes[j + ROWS_AHEAD]``
    and the points of ``nodes[j + POINTS_AHEAD]``. A hint only: no value changes.
    """
    k = j + INC_AHEAD
    if k < hi:
        _prefetch(inc.ctypes.data + ptr[nodes[k]] * inc.strides[0])
    k = j + ROWS_AHEAD
    if k < hi and (dirty[nodes[k]] or not only_dirty):
        _rows(hexes, scale, cq, ptr, inc, nodes[k])
    k = j + POINTS_AHEAD
    if k < hi and (dirty[nodes[k]] or not only_dirty):
        _points(X, hexes, ptr, inc, nodes[k])
