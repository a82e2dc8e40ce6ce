"""``contact_cut._near_any`` tests every candidate against every cut at once (h26/slow): the
same points as the loop over the cuts it replaced, bit for bit (the same sums of squares)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from vmesh.geometry.contact_cut import _near_any


class _Cuts:
    """The members of :class:`~vmesh.geometry.contact_cut.ContactCuts` that ``_near_any`` reads."""

    def __init__(self, centre, reach):
        self.centre, self.reach, self.tree = centre, reach, cKDTree(centre)

    def __len__(self):
        return len(self.centre)


def _near_by_loop(cuts, p):
    """The former loop, one cut at a time."""
    d, _ = cuts.tree.query(p, distance_upper_bound=float(cuts.reach.max()))
    cand = np.flatnonzero(np.isfinite(d))
    near = np.zeros(len(cand), bool)
    for k in range(len(cuts)):
        near |= np.sum((p[cand] - cuts.centre[k]) ** 2, axis=1) < cuts.reach[k] ** 2
    return cand[near]


def test_same_points_as_the_loop_over_the_cuts():
    rng = np.random.default_rng(7)
    for k in (1, 3, 12):
        cuts = _Cuts(rng.uniform(0, 10, (k, 3)), rng.uniform(0.5, 3.0, k))
        for _ in range(200):
            p = rng.uniform(-1, 11, (int(rng.integers(1, 80)), 3))
            # points on a cut's sphere test the strict comparison
            p[:1] = cuts.centre[0] + [cuts.reach[0], 0.0, 0.0]
            got = _near_any(cuts, p)
            assert got.dtype.kind == "i" and np.array_equal(got, _near_by_loop(cuts, p))
    assert len(_near_any(cuts, np.zeros((0, 3)))) == 0
