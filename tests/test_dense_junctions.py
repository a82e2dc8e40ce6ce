"""Dense and close junctions (issue 17): the failure group "N block(s) stay invalid" of
sv_rpa (extracted, node 2), hepatic_artery (extracted, node 11) and the generated corpus,
rebuilt on a small generated vessel.

sv_rpa's node 2: a small branch leaves the trunk alongside a daughter of a bifurcation one
radius downstream, so the first junction's half cross-section between that branch and the
segment to the second junction (less than 25 degrees apart around its axis) reaches past
the second junction. Merging the two gives a 4-junction far out of plane; splitting it
again (any pairing) gives two crowded 3-junctions. ``docs/junctions.md`` ("Dense and close
junctions") has the analysis and what was tried.
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import close_junctions
from vmesh.geometry import cross_sections as cs
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.block_builder import BlockOptions, build_blocks

#: (gap between the junctions in trunk radii, side branch azimuth and elevation in degrees);
#: the upper daughter leaves at (20, -20), 30 degrees below the side branch
DENSE = [(1.0, 20.0, 10.0), (0.6, 20.0, 10.0)]


def _skeleton(case):
    # as clean_skeleton does in the default chain (and test_junctions.build)
    sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    return sk


@pytest.mark.parametrize("gap,azimuth,elevation", DENSE)
def test_generated_vessel_has_a_dense_junction(gap, azimuth, elevation):
    """The regression vessel keeps what makes sv_rpa's node 2 fail: two junctions closer
    than two radii, joined by one segment, and at the first one the side branch less than
    25 degrees from that segment around the junction axis."""
    case = close_junctions(gap, side=(azimuth, elevation))
    sk = _skeleton(case)
    assert len(sk.junctions) == 2
    a, b = (int(x) for x in sk.junctions)
    assert np.linalg.norm(sk.points[a] - sk.points[b]) < 2.0 * sk.radii[a]
    assert sorted(map(int, sk.edges[np.any(sk.edges == a, axis=1) & np.any(sk.edges == b, axis=1)][0])) == [a, b]
    _, least_gap, _ = cs.junction_axis(cs.unit(sk.points[sk.neighbors(a)] - sk.points[a]))
    assert np.degrees(least_gap) < 25.0
    # the field is the vessel: every skeleton node inside it
    assert np.all(case.distance(sk.points) > 0)


@pytest.mark.parametrize("gap,azimuth,elevation", DENSE)
def test_merged_dense_pair_stands_where_the_side_branch_leaves_the_link(gap, azimuth, elevation):
    """``merge_junction_pair(own_lumen=True)`` on the dense pair: the side branch of the
    first junction runs in one lumen with the link past the bifurcation, so the node it
    leaves through (the first past the link's middle outside the link's lumen) projects onto
    the link's far end: the merged 4-junction stands at the bifurcation, not at the link's
    middle (h20/pair), and the side branch leaves it forward, outside the link's lumen."""
    from vmesh.geometry.blocks.prep import merge_junction_pair

    case = close_junctions(gap, side=(azimuth, elevation))
    sk = _skeleton(case)
    a, b = sorted(int(x) for x in sk.junctions)  # a: the side branch's junction at the origin
    out, node = merge_junction_pair(sk, a, b, own_lumen=True)
    assert out.degrees[node] == 4 and out.n_nodes < sk.n_nodes - 1  # fused side-branch nodes taken
    np.testing.assert_allclose(out.points[node], sk.points[b], atol=1e-12)
    first = out.points[out.neighbors(node)] - out.points[node]
    side = first[np.argmax(np.linalg.norm(first[:, 1:], axis=1) / np.linalg.norm(first, axis=1) * (first[:, 2] > 0))]
    # forward from the bifurcation, so its distance from the link's axis is that from its end: outside the lumen
    assert side[0] > 0 and np.linalg.norm(side) >= sk.radii[b]


@pytest.mark.slow
@pytest.mark.parametrize("gap,azimuth,elevation", DENSE)
def test_dense_junction_blocks_valid(gap, azimuth, elevation):
    """Since h16/pair the 0.6 gap builds: merged, the side branch leaves the 4-junction
    clear of the link (``merge_junction_pair``), not along it: its fused nodes past the
    link's middle but inside the link's lumen go into the junction too (h19/pair). Since
    h20/pair the 1.0 gap builds too: the merged junction stands where the side branch
    leaves the link (its first kept node projects onto the bifurcation's end of the link),
    not at the link's middle, where the side branch's first blocks folded (-0.16)."""
    case = close_junctions(gap, side=(azimuth, elevation))
    blocks = build_blocks(_skeleton(case), case.distance, None, BlockOptions(), project=case.project)
    assert blocks.corner_jacobians().min() > 0


def test_merged_pair_stays_at_the_middle_when_one_fused_sibling_leaves_mid_link():
    """Two siblings from one end run fused with the link past its middle; one leaves past
    the other junction, the other mid-link: the merged junction stays at the link's middle
    (moved to the other end, the second sibling would leave it backwards). With the first
    one alone it stands at the other end (h20/pair)."""
    from vmesh.geometry.blocks.prep import merge_junction_pair
    from vmesh.skeleton import Skeleton

    def skeleton(siblings):
        pts, radii, edges = [[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]], [1.0, 1.0, 1.0], [(0, 1), (1, 2)]  # link a=0 .. b=2
        for start, chain, r in [(0, [[-1.0, 0, 0], [-2.0, 0, 0]], 1.0), (2, [[3.0, 0.5, 0], [4.0, 1.0, 0]], 0.7), (2, [[3.0, -0.5, 0], [4.0, -1.0, 0]], 0.7)] + siblings:
            prev = start
            for q in chain:
                pts.append(q)
                radii.append(r)
                edges.append((prev, len(pts) - 1))
                prev = len(pts) - 1
        return Skeleton(np.asarray(pts), np.asarray(radii), np.asarray(edges))

    past = (0, [[1.0, 0.5, 0], [2.5, 1.2, 0], [4.0, 3.0, 0], [5.0, 4.0, 0]], 0.5)  # leaves through (2.5, 1.2): nearest b
    mid = (0, [[0.7, -0.4, 0], [1.5, -1.2, 0], [2.5, -2.5, 0], [3.0, -3.5, 0]], 0.5)  # leaves through (1.5, -1.2): mid-link
    for siblings, at in (([past], [2.0, 0, 0]), ([past, mid], [1.0, 0, 0]), ([mid, past], [1.0, 0, 0])):
        out, node = merge_junction_pair(skeleton(siblings), 0, 2, own_lumen=True)
        np.testing.assert_allclose(out.points[node], at, atol=1e-12)
