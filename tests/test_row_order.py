"""Packed-key row sorting (``repair._row_order``), which replaced ``np.unique(axis=0)`` in
the boundary-layer lines and the face pairing: same order, same labels, same first rows."""

import numpy as np
import pytest

from vmesh.repair import _packed_columns, _row_labels, _row_order


@pytest.mark.parametrize("high", [5, 450_000, 2**40])
def test_row_order_matches_np_unique(high):
    rng = np.random.default_rng(int(np.log2(high)))
    rows = rng.integers(-1, high, size=(4000, 5))
    rows[2000:] = rows[rng.integers(0, 2000, 2000)]  # repeated rows
    order, new = _row_order(rows)
    unique, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    assert np.array_equal(rows[order[new]], unique) and np.array_equal(order[new], first)
    assert np.array_equal(_row_labels(rows), inverse.ravel())
    assert len(_packed_columns(rows)) == (1 if high == 5 else 2 if high == 450_000 else 5)


def test_row_labels_of_float_rows():
    rows = np.array([[0.5, 1.0], [0.0, 2.0], [0.5, 1.0], [-0.0, 2.0]])
    assert list(_row_labels(rows)) == [1, 0, 1, 0]
