"""Sharp bends (SWC tracing corners, hairpins): nodes whose cross-sections would cross inside
the vessel are dropped before the block builder sees them (issue 17: the BraVa whole-brain
SWC failed with "no wall within reach" at a 138-degree corner)."""

import numpy as np
import pytest

from test_blocks import capsule_distance
from vmesh.errors import MeshingError
from vmesh.geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
from vmesh.geometry.skeleton.bends import section_gaps, thin_sharp_bends
from vmesh.geometry.skeleton_ops import resample_skeleton
from vmesh.skeleton import Skeleton


def bent_tube(turn_deg: float, radius: float = 1.0, arm: float = 8.0, kink: float = 0.0):
    """A tube of two straight arms meeting at a corner that turns by ``turn_deg``
    (``kink`` > 0: the corner cut by a short middle piece, two turns of half the angle, as
    a traced centerline has it), its skeleton resampled at 1.25 radii, and its signed
    distance (the union of the arms' capsules: a sharp crease on the inner side)."""
    a = np.radians(turn_deg)
    d0, d1 = np.array([1.0, 0, 0]), np.array([np.cos(a), np.sin(a), 0])
    if kink:
        dm = np.array([np.cos(a / 2), np.sin(a / 2), 0])
        P = np.array([-arm * d0, [0, 0, 0], kink * dm, kink * dm + arm * d1])
    else:
        P = np.array([-arm * d0, [0, 0, 0], arm * d1])
    sk = Skeleton(P, np.full(len(P), radius), np.c_[np.arange(len(P) - 1), np.arange(1, len(P))])
    return resample_skeleton(sk, 1.25), capsule_distance(P[:-1], P[1:], np.full(len(P) - 1, radius))


def test_section_gaps_of_a_straight_tube_and_a_right_angle():
    sk, _ = bent_tube(0.0)
    gap, _, turn = section_gaps(sk)
    assert np.all(np.isinf(gap) | (gap > 1e6)) and np.allclose(turn, 0.0)
    # a right angle at a node with segments of equal length h: the mitre plane (45 degrees)
    # and the perpendicular plane of the next node cross h from the axis
    h = 1.5
    P = np.array([[-2 * h, 0, 0], [-h, 0, 0], [0, 0, 0], [0, h, 0], [0, 2 * h, 0]])
    sk = Skeleton(P, np.ones(5), np.c_[np.arange(4), np.arange(1, 5)])
    gap, side, turn = section_gaps(sk)
    assert np.isclose(np.degrees(turn[2]), 90.0)
    assert np.allclose(gap[[1, 2]], h)
    # towards the inner side of the bend (+y on the first arm)
    assert side[1, 1] > 0.99


@pytest.mark.parametrize("turn, kink", [(120.0, 0.0), (140.0, 0.0), (140.0, 0.45)])
def test_sharp_bends_are_thinned_until_the_blocks_are_valid(turn, kink):
    sk, dist = bent_tube(turn, kink=kink)
    # as resampled, neighbouring sections cross inside the tube: the blocks stay invalid
    with pytest.raises(MeshingError):
        build_blocks(sk, dist, None, BlockOptions())
    thinned, removed = thin_sharp_bends(sk, 1.0, dist)
    assert removed > 0 and thinned.n_nodes == sk.n_nodes - removed
    assert len(thinned.endpoints) == 2 and len(thinned.junctions) == 0 and thinned.n_components == 1
    gap, side, _ = section_gaps(thinned)
    assert np.all(gap >= 1.0)  # at least a radius; near the corner the cast wall is farther
    checks = block_structure_checks(build_blocks(thinned, dist, None, BlockOptions()))
    assert checks["invalid_blocks"] == checks["face_use_errors"] == 0
    assert checks["boundary_euler"] == 2  # wall and end faces: one closed surface


def test_gentle_bends_are_left_alone():
    sk, dist = bent_tube(60.0)
    thinned, removed = thin_sharp_bends(sk, 1.0, dist)
    assert removed == 0 and np.array_equal(thinned.points, sk.points)
