"""The L-BFGS untangler does not fold elements that were valid at its start (issue 17/18,
session 24, h24/untangle; docs/optimiser.md, *The untangler keeps valid elements valid*).

The untangler minimises the functional's sum over a region, not its minimum: where a fold
cannot be opened it can ease the fold by folding a valid neighbour (s0 g0015 extracted:
block 2074, valid in the raw fill, folded by the restart). ``untangle(keep_valid=True)``
(the default) then untangles again with the nodes of such elements held; a result that folds
no valid element is returned unchanged.
"""

from __future__ import annotations

import numpy as np

from test_inverted_output import _held_folds
from vmesh.geometry.quality import hex8_scaled_jacobian
from vmesh.geometry.untangle import untangle


def _untangle(points, cells, held, **kw):
    return untangle(points, cells, 1, boundary=held, threshold=0.2, restart_below=0.2, **kw)


def test_the_untangler_keeps_valid_elements_valid():
    # an 8^3 grid with three held nodes pushed off their places (seed 25): 14 inverted
    # elements at -0.908 no move of the free nodes fully opens; the plain untangler leaves 4
    # at -0.783, one of them valid at the start
    points, cells, held = _held_folds(25)
    q0 = hex8_scaled_jacobian(points, cells)
    assert (q0 <= 0).sum() > 0
    X, plain = _untangle(points, cells, held, keep_valid=False)
    q = hex8_scaled_jacobian(X, cells)
    assert ((q0 > 0) & (q <= 0)).any()
    Y, info = _untangle(points, cells, held)
    qy = hex8_scaled_jacobian(Y, cells)
    assert not ((q0 > 0) & (qy <= 0)).any()  # no element valid at the start is folded
    assert (qy <= 0).sum() <= (q <= 0).sum() and qy.min() >= q.min()
    assert info["keep_valid"]["kept"] and info["keep_valid"]["folded_valid"] == int(((q0 > 0) & (q <= 0)).sum())
    assert np.array_equal(Y[held], points[held])


def test_a_result_that_folds_no_valid_element_is_unchanged():
    points, cells, held = _held_folds(11)
    q0 = hex8_scaled_jacobian(points, cells)
    X, plain = _untangle(points, cells, held, keep_valid=False)
    assert not ((q0 > 0) & (hex8_scaled_jacobian(X, cells) <= 0)).any()
    Y, info = _untangle(points, cells, held)
    assert np.array_equal(X, Y) and "keep_valid" not in info
