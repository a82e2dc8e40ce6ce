"""A vessel that ends a radius or two past a junction, at a closed flat end that no cap was
found on (issue 17, seed 0 g0000 extracted: the end past the junction where a thin kissing
vessel leaves, its noisy end face no cap): the extraction's spur pruning took its short
terminal branch for a spur, the skeleton turned into the side vessel, and the mesh left
the end out (check_coverage: 0.7 % of the wall, 1.2 radii deep). A terminal branch ending
at a flat end face of a tube of its own now stays; a bulge on a wall is still pruned."""

from __future__ import annotations

import numpy as np
import pytest

from vmesh.geometry.skeleton.extract import extract_skeleton

R, SIDE = 1.0, 0.55  # the vessel's and the side vessel's radius


def closed_cylinder(p: np.ndarray, a, b, radius: float) -> np.ndarray:
    """Signed distance (positive inside) of a cylinder with flat ends from ``a`` to ``b``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = np.linalg.norm(b - a)
    u = (b - a) / length
    t = (p - a) @ u
    dr = np.linalg.norm((p - a) - np.outer(t, u), axis=1) - radius
    dz = np.maximum(-t, t - length)
    outside = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0))
    return -(np.minimum(np.maximum(dr, dz), 0) + outside)


def t_vessel(past: float):
    """A vessel along x (radius ``R``) from x = -10 to a flat closed end ``past`` beyond the
    junction at the origin, where a thinner vessel (radius ``SIDE``) leaves along +y."""

    def sdf(p):
        p = np.asarray(p, float).reshape(-1, 3)
        main = closed_cylinder(p, [-10.0, 0, 0], [past, 0, 0], R)
        return np.maximum(main, closed_cylinder(p, [0.0, 0, 0], [0.0, 8.0, 0], SIDE))

    return sdf


@pytest.mark.parametrize("past", [1.2, 2.0])
def test_a_vessel_end_past_a_junction_keeps_its_branch(past):
    skeleton, stats = extract_skeleton(t_vessel(past), ([-10.5, -1.5, -1.5], [past + 0.5, 8.5, 1.5]), min_radius=SIDE)
    ends = skeleton.points[skeleton.degrees == 1]
    beyond = ends[ends[:, 0] > 0.5 * R]
    # before: pruned as a spur (tip ball 1.8-1.9 junction radii out), no end past x = 0
    assert len(beyond) == 1, ends
    end = beyond[0]
    # at the last full cross-section behind the end face, on the axis
    assert past - 0.5 * R < end[0] < past and np.hypot(end[1], end[2]) < 0.1 * R
    assert len(ends) == 3 and stats["spurs"] == 0


def test_a_bulge_on_a_wall_is_still_a_spur():
    def bulged(p):
        p = np.asarray(p, float).reshape(-1, 3)
        tube = closed_cylinder(p, [-10.0, 0, 0], [10.0, 0, 0], R)
        return np.maximum(tube, 0.7 * R - np.linalg.norm(p - [0.0, R, 0], axis=1))

    skeleton, stats = extract_skeleton(bulged, ([-10.5, -1.5, -1.5], [10.5, 2.5, 1.5]), min_radius=R)
    ends = skeleton.points[skeleton.degrees == 1]
    assert len(ends) == 2 and np.abs(ends[:, 1]).max() < 0.1 * R  # the tube's two ends only
    assert stats["spurs"] == 1  # the bulge's branch, pruned as before
