"""A junction's thin sibling running back in the link's lumen past the link's middle,
re-rooted at the other junction as the builder's last try (:mod:`vmesh.geometry.blocks.reroot`,
docs/junctions.md h24/builder): the generator's ``kissing`` branch grown from a vessel next
to a junction (s1 g0012 given's configuration)."""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import retrograde_branch
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.blocks.reroot import reroot_backwards_siblings

#: a link of 1.4 parent radii whose far junction's thin branch (0.4 of the link's radius)
#: leaves 50 degrees from the link back towards the near junction: it leaves the link's
#: lumen past the link's middle; every merge and split fails (main before h24/builder)
SHORT_LINK = dict(gap=1.4, back=50.0, phi=160.0, ratio=0.4)


def _separated(case):
    sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    a, b = (int(c) for c in sk.junctions)
    return sk, a, b


def test_a_backwards_sibling_past_the_links_middle_goes_to_the_other_junction():
    """The near junction gets the branch (4 branches), the far one keeps the link's
    continuation only (a plain node); the branch's nodes inside the link's lumen are gone and
    it leaves through its first node outside the lumen, past a new node inside the vessel."""
    case = retrograde_branch(**SHORT_LINK)
    sk, a, b = _separated(case)
    out = reroot_backwards_siblings(sk, a, b, case.distance)
    assert out is not None
    assert out.degrees[a] == 4 and out.degrees[b] == 2
    new = out.n_nodes - 1
    assert a in out.neighbors(new).tolist() and case.distance(out.points[new][None])[0] > 0
    link_axis = sk.points[b] - sk.points[a]
    beyond = [n for n in out.neighbors(new).tolist() if n != a][0]
    x = out.points[beyond] - out.points[a]
    off = np.linalg.norm(x - (x @ link_axis) / (link_axis @ link_axis) * link_axis)
    assert off >= 0.8  # its first node past the new one lies outside the link's lumen (radius 0.8)
    # nodes: the branch's nodes inside the lumen dropped, one added
    assert out.n_nodes < sk.n_nodes + 1


def test_a_sibling_that_parts_before_the_middle_stays():
    """At 4 radii the backwards branch's tube leaves the link's lumen before the link's
    middle: the merges serve it, no re-root."""
    case = retrograde_branch(4.0, ratio=0.4)
    sk, a, b = _separated(case)
    assert reroot_backwards_siblings(sk, a, b, case.distance) is None


def test_a_sibling_as_thick_as_the_link_stays():
    """A branch as thick as the link whose tube runs fused with it past the middle is an
    ordinary daughter (:data:`~vmesh.geometry.blocks.reroot.THIN_SHARE`), not re-rooted."""
    case = retrograde_branch(1.8, back=45.0, phi=160.0, ratio=1.0)
    sk, a, b = _separated(case)
    assert reroot_backwards_siblings(sk, a, b, case.distance) is None


#: the link 1.8 parent radii, the thin branch 45 degrees back (as the generator's kissing
#: tube, s1 g0016 given): its axis leaves the link's lumen at its first node past the
#: middle, its tube one node later; re-rooted through the axis' node the build fails
#: (10 blocks, -1.15), through the tube's it builds (h26/backwards)
TUBE_PAST_AXIS = dict(gap=1.8, back=45.0, phi=160.0, ratio=0.4)


@pytest.mark.parametrize("gap", [2.2, 1.8])
def test_a_sibling_whose_tube_runs_fused_past_the_middle_is_re_rooted_where_its_tube_clears(gap):
    """The sibling is judged by its tube (:data:`~vmesh.geometry.blocks.reroot.TUBE_CLEARANCE`):
    where its axis leaves the link's lumen before (2.2 radii) or at (1.8) the link's middle
    and its tube only past it, it is re-rooted, through its first node whose tube clears
    the lumen (the axis' first node outside would leave the tube fused with the link)."""
    from vmesh.geometry.blocks import reroot

    case = retrograde_branch(**{**TUBE_PAST_AXIS, "gap": gap})
    sk, a, b = _separated(case)
    out = reroot_backwards_siblings(sk, a, b, case.distance)
    assert out is not None and out.degrees[a] == 4 and out.degrees[b] == 2
    new = out.n_nodes - 1
    beyond = [n for n in out.neighbors(new).tolist() if n != a][0]
    link_axis = sk.points[b] - sk.points[a]
    x = out.points[beyond] - out.points[a]
    off = np.linalg.norm(x - (x @ link_axis) / (link_axis @ link_axis) * link_axis)
    assert off >= 0.8 + out.radii[beyond] * reroot.TUBE_CLEARANCE - 0.05  # its tube clear of the link's lumen (radius 0.8)


@pytest.mark.slow
def test_a_thin_backwards_branch_leaving_the_link_past_its_middle_builds():
    """The builder's last try (``reroot_backwards``, opt-in): valid blocks, the pair's wall
    still covered, the note in the fixes; off (the default), the build fails."""
    _rerooted_blocks(SHORT_LINK)


def _rerooted_blocks(shape: dict):
    """``retrograde_branch(**shape)`` built with ``reroot_backwards``: every block valid, the
    re-root in the fixes, the pair's wall covered; the default build fails. Returns (case, blocks)."""
    from vmesh.errors import MeshingError
    from vmesh.geometry.blocks.checks import wall_left_out
    from vmesh.geometry.blocks.prep import MERGE_COVER_DEPTH, pair_wall

    case = retrograde_branch(**shape)
    sk, a, b = _separated(case)
    blocks = build_blocks(sk, case.distance, None, BlockOptions().replace(reroot_backwards=True), project=case.project)
    assert blocks.corner_jacobians().min() > 0
    assert any("re-rooted" in note for note in blocks.info["fixes"])
    assert wall_left_out(blocks, case.project, *pair_wall(sk, a, b, case.project)).max() <= MERGE_COVER_DEPTH
    with pytest.raises(MeshingError):
        build_blocks(sk, case.distance, None, BlockOptions(), project=case.project)  # off by default
    return case, blocks


def test_ring_placements_lie_in_the_new_segments_section():
    """The new first node's ring placements: ``PLACEMENT_RINGS`` × the branch's radius from
    the section's centre, in the plane normal to the new first segment, inner ring first."""
    from vmesh.geometry.blocks.reroot import PLACEMENT_DIRECTIONS, PLACEMENT_RINGS, N_PLACEMENTS, section_placements

    centre, tangent, radius = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.6, 0.8]), 0.5
    ring = section_placements(centre, tangent, radius)
    assert ring.shape == (N_PLACEMENTS - 1, 3) == (len(PLACEMENT_RINGS) * PLACEMENT_DIRECTIONS, 3)
    off = ring - centre
    np.testing.assert_allclose(off @ tangent, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(off, axis=1), np.repeat(PLACEMENT_RINGS, PLACEMENT_DIRECTIONS) * radius)


def test_a_ring_placement_moves_the_new_node_and_puts_the_far_junction_on_the_chord():
    """Placement k > 0: the same re-rooted topology as the deepest point (placement 0), the
    new node at its ring point (inside the vessel) and the far junction, now a plain node
    of the link, on the chord between its two neighbours."""
    from vmesh.geometry.blocks.reroot import N_PLACEMENTS

    case = retrograde_branch(**SHORT_LINK)
    sk, a, b = _separated(case)
    deepest = reroot_backwards_siblings(sk, a, b, case.distance, 0)
    built = 0
    for k in range(1, N_PLACEMENTS):
        out = reroot_backwards_siblings(sk, a, b, case.distance, k)
        if out is None:
            continue  # that ring point lies outside the wall
        built += 1
        assert out.n_nodes == deepest.n_nodes and out.degrees[a] == 4 and out.degrees[b] == 2
        new = out.n_nodes - 1
        assert case.distance(out.points[new][None])[0] > 0 and out.radii[new] > 0
        assert np.linalg.norm(out.points[new] - deepest.points[new]) > 0
        p, q = (out.points[n] for n in out.neighbors(b))
        x = out.points[b] - p
        assert np.linalg.norm(np.cross(q - p, x)) <= 1e-9 * np.linalg.norm(q - p) ** 2  # on the chord
    assert built >= N_PLACEMENTS // 2


@pytest.mark.slow
def test_a_backwards_sibling_whose_tube_runs_past_the_middle_meshes():
    """The kissing configuration whose tube, not axis, runs fused past the link's middle
    (s1 g0016 given's): with ``reroot_backwards`` every block valid, the pair's wall
    covered, and the mesh, untangled as ``mesh_transfinite`` does, has no inverted element;
    the default build fails."""
    from vmesh.filters.mesh_filters import _constraints
    from vmesh.geometry.quality import scaled_jacobian
    from vmesh.geometry.transfinite import Refinement, mesh_blocks
    from vmesh.geometry.untangle import untangle

    case, blocks = _rerooted_blocks(TUBE_PAST_AXIS)
    sm = mesh_blocks(blocks, case.project, Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02),
                     signed_distance=case.distance)
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    X, _ = untangle(sm.points, sm.cells, 1, wall=wall, wall_normals=case.gradient, project=case.project, cap_nodes=cap_nodes,
                    cap_normals=cap_normals, boundary=boundary)
    assert scaled_jacobian(X, sm.cells, 1).min() > 0
