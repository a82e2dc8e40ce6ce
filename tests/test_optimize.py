"""The local mesh optimiser (vmesh.geometry.optimize) on deliberately folded O-grid cylinders."""

import numpy as np
import pytest

from cylinder_blocks import cylinder_blocks, optimiser_constraints, project_cylinder
from vmesh.geometry.optimize import corner_index, follow_corners, optimise
from vmesh.geometry.quality import hex8_scaled_jacobian, scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks, reference_points
from vmesh.geometry.untangle import sub_hexahedra

R = 2.0
FIRST = 0.02  # first boundary-layer element thickness relative to the radius


def cylinder(order=1):
    blocks = cylinder_blocks(radius=R)
    sm = mesh_blocks(blocks, project_cylinder(R), Refinement(around=4, core=4, ring=3, layer=4, element_length=0.5, first_layer=FIRST, order=order))
    return sm, optimiser_constraints(sm, R)


def first_layer_nodes(sm):
    """Interior nodes one edge away from a wall node (the top of the first boundary layer)."""
    sub, _ = sub_hexahedra(sm.cells, sm.order)
    wall = sm.on_wall
    out = np.zeros(len(sm.points), bool)
    for c in range(8):
        for a in range(3):
            u, w = sub[:, c], sub[:, c ^ (1 << a)]
            out[w[wall[u] & ~wall[w]]] = True
    return out


def corner_nodes(sm):
    return sm.cells[:, corner_index(sm.order)]


def fold_interior(sm, count=6, seed=1):
    """Push ``count`` interior element corners through their neighbours (by about one element)."""
    rng = np.random.default_rng(seed)
    X = sm.points.copy()
    corner = np.zeros(len(X), bool)
    corner[corner_nodes(sm).ravel()] = True
    inner = np.flatnonzero(corner & (np.abs(X[:, 2] - 5) < 3) & (np.linalg.norm(X[:, :2], axis=1) < 1.5))
    pick = rng.choice(inner, count, replace=False)
    X[pick] += rng.normal(size=(count, 3)) * 0.6
    if sm.order > 1:  # the high-order nodes follow the folded corners
        X = follow_corners(sm.points, sm.cells, sm.order, X, reference_points(sm.order))
    return X


def check_boundary(sm, kw, X0, X):
    wall, caps = kw["wall"], kw["cap_nodes"]
    assert np.abs(np.linalg.norm(X[wall, :2], axis=1) - R).max() < 1e-9  # wall nodes on the wall
    assert np.abs(X[caps, 2] - X0[caps, 2]).max() < 1e-12  # cap nodes in their plane
    rim = kw["boundary"] & ~wall & ~caps | (wall & caps)
    assert np.array_equal(X[rim], X0[rim])


def test_folded_interior_is_untangled_locally():
    sm, kw = cylinder()
    X0 = fold_interior(sm)
    assert (hex8_scaled_jacobian(X0, sm.cells) <= 0).sum() > 10
    X, info = optimise(X0, sm.cells, 1, **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.min() > 0.3
    check_boundary(sm, kw, X0, X)
    moved = np.any(X != X0, axis=1)
    assert moved.sum() == info["moved"] and moved.mean() < 0.06
    X2, _ = optimise(X0, sm.cells, 1, **kw)
    assert np.array_equal(X, X2)  # deterministic (parallel over each colour only)


def test_sheared_boundary_layer_keeps_its_first_height():
    """Wall nodes twisted along the wall fold the boundary layer; untangling slides them
    back on the wall and the first-layer height stays within a few per cent."""
    sm, kw = cylinder()
    X0 = sm.points.copy()
    top = first_layer_nodes(sm)
    height0 = R - np.linalg.norm(X0[top, :2], axis=1)
    wall = kw["wall"] & ~kw["cap_nodes"]
    z = X0[:, 2]
    twist = np.where(wall & (np.abs(z - 5) < 1.3), 0.25, 0.0)  # radians, a band of the wall
    c, s = np.cos(twist), np.sin(twist)
    Xt = X0.copy()
    Xt[:, 0], Xt[:, 1] = c * X0[:, 0] - s * X0[:, 1], s * X0[:, 0] + c * X0[:, 1]
    assert (hex8_scaled_jacobian(Xt, sm.cells) <= 0.1).any()
    X, info = optimise(Xt, sm.cells, 1, **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.min() > 0.2 and info["after"]["min"] == pytest.approx(q.min())
    check_boundary(sm, kw, Xt, X)
    height = R - np.linalg.norm(X[top, :2], axis=1)
    assert np.abs(height / height0 - 1).max() < 0.05


def test_boundary_layer_twisted_over_a_long_band_is_untangled_with_its_top_nodes_free():
    """kd_lima extracted: a boundary-layer block twisted along a curved wall, all its layers
    folded. With the first-layer nodes held at their wall distance the local untangler
    stays below 0.3 (wall and top nodes can only slide); untangling again from the initial
    mesh with them free, every step judged by its worst element, gets above 0.3 and is
    kept, with the walls and caps kept and few nodes moved."""
    sm, kw = cylinder()
    X0 = sm.points.copy()
    wall = kw["wall"] & ~kw["cap_nodes"]
    twist = np.where(wall & (np.abs(X0[:, 2] - 5) < 1.3), 0.6, 0.0)  # radians
    c, s = np.cos(twist), np.sin(twist)
    Xt = X0.copy()
    Xt[:, 0], Xt[:, 1] = c * X0[:, 0] - s * X0[:, 1], s * X0[:, 0] + c * X0[:, 1]
    assert (hex8_scaled_jacobian(Xt, sm.cells) < 0).sum() > 100
    X, info = optimise(Xt, sm.cells, 1, untangle_below=0.3, **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert info["free_layer"]["held_min"] < 0.3 and info["free_layer"]["kept"]
    assert q.min() > 0.3
    check_boundary(sm, kw, Xt, X)
    assert np.any(X != Xt, axis=1).mean() < 0.1


def test_valid_mesh_never_gets_worse():
    sm, kw = cylinder()
    rng = np.random.default_rng(3)
    X0 = sm.points.copy()
    free = ~kw["boundary"] & (np.linalg.norm(X0[:, :2], axis=1) < 1.5)  # off the thin boundary layer
    X0[free] += rng.normal(size=(free.sum(), 3)) * 0.015
    q0 = hex8_scaled_jacobian(X0, sm.cells)
    assert q0.min() > 0
    X, info = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert info["moved"] > 0
    assert q.min() >= q0.min() and q.mean() >= q0.mean()
    check_boundary(sm, kw, X0, X)


def test_nothing_moves_on_a_good_mesh():
    sm, kw = cylinder()
    X, info = optimise(sm.points, sm.cells, 1, untangle_below=0.3, smooth_below=0.5, **kw)
    assert info["moved"] == 0 and np.array_equal(X, sm.points)


def test_order_2_mesh_is_untangled_and_its_high_order_nodes_follow():
    sm, kw = cylinder(order=2)
    X0 = fold_interior(sm, count=4, seed=5)
    ref = reference_points(2)
    assert scaled_jacobian(X0, sm.cells, 2, ref).min() <= 0
    X, info = optimise(X0, sm.cells, 2, **kw)
    assert scaled_jacobian(X, sm.cells, 2, ref).min() > 0
    assert info["followed_nodes"] > 0
    check_boundary(sm, kw, X0, X)


def _jittered_cylinder():
    """A curved O-grid cylinder with its free interior nodes jittered by 1e-4 radii: a mesh
    of a real vessel is never exactly symmetric, and at an exactly symmetric node two mirror
    elements tie for the worst and no monotone step helps both."""
    blocks = cylinder_blocks(radius=R)
    sm = mesh_blocks(blocks, project_cylinder(R), Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=FIRST, curved_sections=True))
    kw = optimiser_constraints(sm, R)
    X0 = sm.points.copy()
    free = ~kw["boundary"] & ~first_layer_nodes(sm)
    X0[free] += np.random.default_rng(0).normal(size=(free.sum(), 3)) * 1e-4 * R
    return blocks, sm, kw, X0, hex8_scaled_jacobian(X0, sm.cells)


def test_light_pass_raises_the_mean_and_keeps_the_boundary_layer():
    """The default light pass (every element below 0.95, no untangling) on a curved O-grid:
    the mean rises, no neighbourhood minimum drops, wall nodes stay on the wall, the first
    boundary-layer height is kept exactly and the node lines across the boundary layer stay
    graded outward (the re-grading to an exact first height stays valid)."""
    blocks, sm, kw, X0, q0 = _jittered_cylinder()
    X, info = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.mean() > q0.mean() + 0.005 and q.min() >= q0.min()
    assert info["smoothed_nodes"] > 0.05 * len(X) and info["untangled_nodes"] == 0
    check_boundary(sm, kw, X0, X)
    top = first_layer_nodes(sm)
    assert np.allclose(np.linalg.norm(X[top, :2], axis=1), np.linalg.norm(X0[top, :2], axis=1), rtol=0, atol=1e-9)
    # boundary-layer node lines: wall distance grows along every line, element by element
    layer = blocks.block_layer[sm.cell_block] == 2
    cells = sm.cells[layer]
    r = np.linalg.norm(X[:, :2], axis=1)
    radial = np.abs(r[cells[:, 1]] - r[cells[:, 0]]) > np.abs(r[cells[:, 2]] - r[cells[:, 0]])  # i runs across the layer
    a, b = np.where(radial, cells[:, 0], cells[:, 0]), np.where(radial, cells[:, 1], cells[:, 2])
    r0 = np.linalg.norm(X0[:, :2], axis=1)
    assert np.all(np.sign(r[b] - r[a]) == np.sign(r0[b] - r0[a]))


def test_serial_and_parallel_kernels_are_cached_apart():
    """numba's disk cache is keyed on a function's name and signature, not on ``parallel=``:
    the serial and parallel variants of a kernel need names of their own, or one loads the
    other's compiled code (the serial sweep then launched threads for every small colour)."""
    from numba.core.caching import FunctionCache

    from vmesh.geometry.optimize import kernels as K

    variants = (K.sweep_colour_serial, K.sweep_colour_parallel, K.accept_trials_serial, K.accept_trials_parallel)
    assert len({FunctionCache(f.py_func)._impl.filename_base for f in variants}) == len(variants)
    assert not K.sweep_colour_serial.targetoptions.get("parallel") and K.sweep_colour_parallel.targetoptions.get("parallel")


def test_light_pass_tolerance_skips_converged_nodes_and_keeps_the_guarantees():
    """``smooth_tol``: a node that moves less than that fraction of its step cap does not
    make its neighbours worth another try. Fewer node updates; the light pass's guarantees (minimum and mean do not drop, walls, caps
    and the first boundary-layer height kept) stay, and the mean gain stays close."""
    blocks, sm, kw, X0, q0 = _jittered_cylinder()
    X_all, all_info = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, smooth_tol=0.0, **kw)
    X, info = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, smooth_tol=0.01, **kw)
    q, q_all = hex8_scaled_jacobian(X, sm.cells), hex8_scaled_jacobian(X_all, sm.cells)
    assert info["updates"] < all_info["updates"]
    assert q.min() >= q0.min() and q.mean() > q0.mean() + 0.005
    assert q.mean() > q_all.mean() - 0.1 * (q_all.mean() - q0.mean())  # most of the gain stays
    check_boundary(sm, kw, X0, X)
    top = first_layer_nodes(sm)
    assert np.allclose(np.linalg.norm(X[top, :2], axis=1), np.linalg.norm(X0[top, :2], axis=1), rtol=0, atol=1e-9)


def test_refused_wall_step_is_retried_with_half_the_step():
    """A wall node gets one (projected) trial per sweep; when the projection of its full step
    is refused it tries again next sweep with half the step (its step cap halves), where it
    used to wait for a neighbour to move. Only the wall nodes of a curved O-grid are free,
    jittered along the wall until elements fold: the light pass alone unfolds them (it left
    the minimum at -0.015 while refused wall nodes stayed put)."""
    blocks = cylinder_blocks(radius=R)
    sm = mesh_blocks(blocks, project_cylinder(R), Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=FIRST, curved_sections=True))
    kw = optimiser_constraints(sm, R)
    wall = kw["wall"] & ~kw["cap_nodes"]
    ids = np.flatnonzero(wall)
    rng = np.random.default_rng(0)
    X0 = sm.points.copy()
    angle = np.arctan2(X0[ids, 1], X0[ids, 0]) + rng.normal(size=len(ids)) * 0.04
    X0[ids, 0], X0[ids, 1] = R * np.cos(angle), R * np.sin(angle)
    X0[ids, 2] += rng.normal(size=len(ids)) * 0.04
    q0 = hex8_scaled_jacobian(X0, sm.cells)
    assert q0.min() < 0
    only_wall = dict(kw, wall=wall, boundary=np.ones(len(X0), bool), cap_nodes=None, cap_normals=None)
    X, info = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, **only_wall)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.min() > 0.5 and q.mean() > q0.mean()
    assert np.array_equal(X[~wall], X0[~wall])
    assert np.abs(np.linalg.norm(X[wall, :2], axis=1) - R).max() < 1e-9


def _untangled_trifurcation():
    """Generated trifurcation (60 degrees, daughters half the parent's radius) with planar
    half cross-sections (``junction_lean=0``; the leaning ones fill it validly): its raw
    fill folds at the crotch, the global L-BFGS untangler leaves it valid but below 0.3."""
    from junction_cases import trifurcation
    from test_junctions import DEFAULT

    from vmesh.filters.mesh_filters import _constraints
    from vmesh.geometry.blocks import BlockOptions, build_blocks
    from vmesh.geometry.untangle import untangle

    case = trifurcation(60, 2)
    blocks = build_blocks(case.skeleton, case.distance, None, BlockOptions(junction_lean=0.0), project=case.project)
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    kw = dict(wall=wall, wall_normals=case.gradient, project=case.project, cap_nodes=cap_nodes, cap_normals=cap_normals, boundary=boundary)
    X, _ = untangle(sm.points, sm.cells, 1, threshold=0.3, restart_below=0.3, **kw)
    return case, sm, kw, X


@pytest.mark.slow
def test_polish_lifts_what_the_global_untangler_left_below_the_goal():
    """The L-BFGS untangler stops where its functional is stationary (g0018, g0001: 0.18,
    0.29 at junction crotches and slanted caps), and the monotone light pass cannot climb
    further. ``polish``, the local untangler started from that mesh with every step judged
    by its worst element, lifts the minimum past the untangling goal, moving few nodes,
    wall nodes on the wall, cap nodes in their planes."""
    from vmesh.geometry.optimize import polish

    case, sm, kw, X0 = _untangled_trifurcation()
    q0 = hex8_scaled_jacobian(X0, sm.cells)
    assert 0 < q0.min() < 0.3
    X, info = polish(X0, sm.cells, (0.3, 0.5), **kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.min() > 0.3 and info["after"] == pytest.approx(q.min())
    moved = np.any(X != X0, axis=1)
    assert moved.mean() < 0.05
    wall, caps = kw["wall"], kw["cap_nodes"]
    assert np.abs(case.distance(X[wall & moved])).max() < 1e-6
    rim = kw["boundary"] & ~wall & ~caps | (wall & caps)
    assert np.array_equal(X[rim], X0[rim])
    plane = caps & ~wall & moved
    assert np.abs(np.einsum("ij,ij->i", X[plane] - X0[plane], kw["cap_normals"][plane])).max(initial=0.0) < 1e-9


def test_polish_never_lowers_the_minimum_and_leaves_inverted_meshes_alone():
    """Each try is kept only when it raises the minimum; a mesh with an inverted element is
    the untanglers' to fix, not this climb's."""
    from vmesh.geometry.optimize import polish

    sm, kw = cylinder()
    X0 = fold_interior(sm)
    X, info = polish(X0, sm.cells, (0.3, 0.5), **kw)
    assert np.array_equal(X, X0) and not info["tries"]
    X1, _ = optimise(X0, sm.cells, 1, untangle_below=0.3, smooth_below=0.0, **kw)
    q1 = hex8_scaled_jacobian(X1, sm.cells).min()
    X2, info = polish(X1, sm.cells, (0.6, 0.9), **kw)
    assert hex8_scaled_jacobian(X2, sm.cells).min() >= q1 and info["after"] >= q1
    check_boundary(sm, kw, X1, X2)


@pytest.mark.slow
def test_polish_after_the_untangler_may_rework_the_region_it_untangled():
    """``mesh_transfinite``'s polish climbs within as many nodes as the untangler moved (sv_rpa
    given: a dense junction's fold untangled over 6,640 nodes left ~20 elements balanced at
    0.29 that no climb within 1 % of the mesh could lift): on the generated trifurcation it
    lifts the minimum past the goal, the wall nodes stay on the wall, rims fixed, and it moves
    no more nodes than its two tries' budgets."""
    from vmesh.filters.mesh_filters import _polish

    case, sm, kw, X0 = _untangled_trifurcation()
    untangled = int(np.any(X0 != sm.points, axis=1).sum())
    assert untangled > 0.01 * len(X0)  # a fold wider than 1 % of the mesh
    info = {"moved": untangled}
    X = _polish(X0, sm, info, (0.3, 0.5), kw)
    q = hex8_scaled_jacobian(X, sm.cells)
    assert q.min() > 0.3 and info["after"] == pytest.approx(q.min())
    moved = np.any(X != X0, axis=1)
    assert moved.sum() <= 2 * untangled
    wall = kw["wall"]
    assert np.abs(case.distance(X[wall & moved])).max() < 1e-6
    rim = kw["boundary"] & ~wall & ~kw["cap_nodes"] | (wall & kw["cap_nodes"])
    assert np.array_equal(X[rim], X0[rim])
