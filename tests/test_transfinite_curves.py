"""Curved cross-section interfaces (vmesh.geometry.transfinite_curves): balanced angles at
the corners of the core and of the ring, valid at every refinement, order and grading,
block corners and wall nodes unchanged, and junction half-sections filled validly."""

import numpy as np
import pytest

from cylinder_blocks import cylinder_blocks, project_cylinder
from junction_cases import bifurcation
from vmesh.blocks import LAYER_RING
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks, reference_points
from vmesh.geometry.transfinite_curves import curved_edges, edge_turns
from vmesh.geometry.transfinite_lattice import block_topology

R = 2.0


def fill(blocks, project, curved, distance=None, **kw):
    ref = Refinement(curved_sections=curved, **kw)
    sm = mesh_blocks(blocks, project, ref, signed_distance=distance)
    return sm, scaled_jacobian(sm.points, sm.cells, ref.order, reference_points(ref.order, ref.nodes))


def test_turns_balance_the_corner_angles():
    blocks = cylinder_blocks(radius=R)
    topo = block_topology(blocks)
    turn, normal = edge_turns(blocks, topo, blocks.vertices)
    V = blocks.vertices
    r = np.linalg.norm(V[:, :2], axis=1)
    curved = np.flatnonzero(np.any(turn != 0, axis=1))
    # only interface edges inside the vessel curve, in the plane of their cross-section
    assert len(curved) and not blocks.vertex_on_surface[topo.edges[curved]].any()
    assert np.allclose(V[topo.edges[curved, 0], 2], V[topo.edges[curved, 1], 2])
    assert np.allclose(normal[curved, 2], 0)
    # core corners (the farthest core points): 90° + 2 * 15° = 120° for the core element
    core_r = 0.35 * R * np.sqrt(2)
    at_corner = np.isclose(r[topo.edges[curved]], core_r)
    assert np.allclose(np.degrees(turn[curved][at_corner]), 15, atol=0.1)
    # ring corners on a regular octagon: 135° + 2 * 22.5° = 180°, a smooth circle
    at_ring = np.isclose(r[topo.edges[curved]], 0.8 * R)
    assert np.allclose(np.degrees(turn[curved][at_ring]), 22.5, atol=0.1)
    # normals point out of the core, towards the wall
    mid = V[topo.edges[curved]].mean(axis=1)
    assert (np.einsum("ij,ij->i", normal[curved, :2], mid[:, :2]) > 0).all()


def test_curved_edges_keep_ends_and_arc_length_spacing():
    a, b = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]])
    t = np.linspace(0, 1, 9)[None]
    pts = curved_edges(a, b, t, np.radians([[20.0, 20.0]]), np.array([[0.0, 1, 0]]))
    assert np.allclose(pts[0, 0], a[0]) and np.allclose(pts[0, -1], b[0])
    seg = np.linalg.norm(np.diff(pts[0], axis=0), axis=1)
    assert np.ptp(seg) < 0.01 * seg.mean()
    assert (pts[0, 1:-1, 1] > 0).all()  # bulges towards the normal
    # symmetric turns: symmetric curve, tangent at the start turned by 20°
    assert np.allclose(pts[0, :, 1], pts[0, ::-1, 1], atol=1e-3)


@pytest.mark.parametrize("around,order", [(2, 1), (4, 1), (6, 1), (2, 2), (2, 3), (3, 4)])
def test_cylinder_curved_valid_and_better(around, order):
    blocks = cylinder_blocks(radius=R)
    kw = dict(around=around, core=around, ring=2, layer=3, order=order, first_layer=0.02)
    sm0, sj0 = fill(blocks, project_cylinder(R), False, **kw)
    sm1, sj1 = fill(blocks, project_cylinder(R), True, **kw)
    # same lattice: same elements, block corners and wall nodes where they were
    assert np.array_equal(sm0.cells, sm1.cells)
    nv = len(blocks.vertices)
    assert np.array_equal(sm0.points[:nv], sm1.points[:nv])
    assert np.allclose(sm0.points[sm0.on_wall], sm1.points[sm1.on_wall])
    assert sj1.min() > 0.5
    ring = blocks.block_layer[sm1.cell_block] == LAYER_RING
    assert sj1[ring].min() > sj0[ring].min() + 0.02
    assert sj1.mean() > sj0.mean()


def test_junction_half_sections_fill_validly():
    case = bifurcation(90, 1)
    sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    blocks = build_blocks(sk, case.distance, None, BlockOptions(), project=case.project)
    for order in (1, 2):
        kw = dict(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02, order=order)
        _, sj0 = fill(blocks, case.project, False, case.distance, **kw)
        _, sj1 = fill(blocks, case.project, True, case.distance, **kw)
        assert sj1.min() > 0
        assert sj1.mean() > sj0.mean()
