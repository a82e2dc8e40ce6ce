"""An open end's cap through a vessel it touches (issue 18, h18/cap): the wall projector
keeps another vessel's points on a cap, as the builder's rays (cast in the closed
surface) do, and a contact cut stops at an open end."""

from __future__ import annotations

import numpy as np
import pytest

from vmesh import preprocess as pre
from vmesh.geometry.contact_cut import CutSurface, contact_cuts
from vmesh.geometry.projection import ON_CAP, CapKeepingProjector, wall_projector
from vmesh.surface import SurfaceMesh


def _capped_tube(radius=1.0, length=6.0, n_around=48, n_along=25):
    """A tube along z capped at both ends: the surface and its caps."""
    from test_preprocess import open_tube

    v, f = open_tube(radius, length, n_around, n_along)
    cv, cf, labels = pre.cap_boundary_loops(v, f)
    return SurfaceMesh(cv, cf), pre.caps_from_labels(cv, cf, labels)


def test_a_point_on_a_cap_far_from_the_wall_stays_there():
    """With both caps touched by another vessel, on the cap's plane: a point half a radius in goes nowhere (it is another vessel's,
    whose lumen the cap closes), a point a chord's sagitta inside the rim goes to the wall
    (the open end's own rim), and a point inside the tube near the wall goes to the wall."""
    surface, caps = _capped_tube()
    assert not isinstance(wall_projector(surface, caps), CapKeepingProjector)  # no cap touched: caps left out
    project = wall_projector(surface, caps, kept=[c.id for c in caps])
    assert isinstance(project, CapKeepingProjector)
    on_cap = np.array([[0.5, 0.0, 6.0], [0.0, -0.4, 0.0]])
    closest, d, face = project.project(on_cap)
    np.testing.assert_allclose(closest, on_cap, atol=1e-9)
    assert (face == ON_CAP).all() and np.allclose(d, 0.0, atol=1e-9)  # not ON_CUT: no contact cut there
    rim = np.array([[0.99, 0.0, 6.0], [0.0, 0.97, 0.0]])
    inside = np.array([[0.9, 0.0, 3.0], [0.0, -0.8, 5.5]])
    for p in (rim, inside):
        closest, _, face = project.project(p)
        assert (face >= 0).all()
        np.testing.assert_allclose(np.linalg.norm(closest[:, :2], axis=1), 1.0, atol=2e-3)


def test_a_contact_cut_stops_at_an_open_end():
    """Two tubes whose axes lie 0.9 apart (radii 1 and 0.45: the thin one's axis inside the
    thick one's wall, its radical plane beyond the thin axis); the thick one ends open at
    y = 0 (its end node on a cap), the thin one runs on. Before the end the cut is there as
    before; past it the thin vessel alone fills the lumen and no cut halves it."""
    y = np.arange(-8.0, 4.01, 1.0)
    thick = np.stack([np.zeros(9), y[:9], np.zeros(9)], 1)  # y = -8 .. 0, end node last
    thin = np.stack([np.full(len(y), 0.9), y, np.zeros(len(y))], 1)
    points = np.r_[thick, thin]
    radii = np.r_[np.full(9, 1.0), np.full(len(y), 0.45)]
    edges = np.r_[np.stack([np.arange(8), np.arange(1, 9)], 1), 9 + np.stack([np.arange(len(y) - 1), np.arange(1, len(y))], 1)]
    end, beside = 8, 9 + 8  # the thick end node and the thin node beside it
    found = np.array([[end, beside, -0.55]])

    def inside(p):  # the union of the two tubes (infinite along y past the thick end for the thin one)
        p = np.asarray(p, float).reshape(-1, 3)
        in_thick = (1.0 - np.hypot(p[:, 0], p[:, 2])) * (p[:, 1] <= 0) - (p[:, 1] > 0)
        return np.maximum(in_thick, 0.45 - np.hypot(p[:, 0] - 0.9, p[:, 2]))

    class Query:
        distance = staticmethod(inside)

        @staticmethod
        def project(p):
            p = np.asarray(p, float).reshape(-1, 3)
            return p, inside(p), np.zeros(len(p), np.int64)

    rounded = contact_cuts(points, radii, edges, found)
    ended = contact_cuts(points, radii, edges, found, open_ends=[end])
    assert len(rounded) == len(ended) == 1 and ended.open_end is not None and ended.open_end[0, 0]
    c, n = ended.centre[0], ended.normal[0]
    before, past = c * [1, 0, 1] + [0.0, -0.5, 0.0], c * [1, 0, 1] + [0.0, 0.4, 0.0]  # plane points in the thin lumen, y = -0.5, 0.4
    for p in (before, past):
        assert abs((p - c) @ n) < 1e-9 and inside(p)[0] > 0
    near = lambda p: p[None] + 0.05 * n  # noqa: E731
    assert CutSurface(Query, rounded).distance(near(past))[0] < 0.06  # the old patch reached past the end
    assert CutSurface(Query, ended).distance(near(past))[0] > 0.06
    np.testing.assert_allclose(CutSurface(Query, ended).distance(near(before)), 0.05, atol=1e-9)


def test_wall_nodes_kept_on_a_touched_cap_are_measured_to_it():
    """check_coverage's wall-node distances use the mesher's projector: a node the mesher kept
    on a cap another vessel touches lies on the input boundary (distance 0), not a radius
    off the wall (the inflated ``wall_node_max_rel`` of contact runs)."""
    from vmesh.geometry.coverage import _wall_node_distances

    surface, caps = _capped_tube()
    kept = wall_projector(surface, caps, kept=[c.id for c in caps])
    X = np.array([[0.0, 0.0, 6.0], [1.0, 0.0, 5.0], [0.0, 1.0, 5.0], [0.0, -1.0, 5.0]])  # the first on the top cap's centre
    faces, ids = np.array([[0, 1, 2, 3]]), np.array([0])
    skeleton = (np.array([[0.0, 0, 0], [0, 0, 6]]), np.array([[0, 1]]), np.ones(2))
    plain = _wall_node_distances(X, faces, ids, wall_projector(surface, caps).tree, *skeleton)[1]
    measured = _wall_node_distances(X, faces, ids, kept, *skeleton)[1]
    assert plain[0] == pytest.approx(1.0, abs=0.01) and measured[0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(measured[1:], plain[1:], atol=1e-12)


def test_coarse_surface_keeps_its_caps():
    """``mesh_transfinite.project_to = "coarse"`` projected onto the whole coarse surface (its
    caps dropped: the cap triangles are the fine surface's), so a touched cap was no longer
    kept and the open ends' rim nodes could land on the cap planes. ``caps_on`` finds each
    cap's triangles on another triangulation of the surface."""
    from test_preprocess import open_tube
    from vmesh.geometry.projection import caps_on

    fine, caps = _capped_tube()
    v, f = open_tube(1.0, 6.0, 24, 9)
    cv, cf, labels = pre.cap_boundary_loops(v, f)
    coarse = SurfaceMesh(cv, cf)
    on = caps_on(coarse, fine, caps)
    for cap, own in zip(on, pre.caps_from_labels(cv, cf, labels)):
        assert sorted(cap.faces.tolist()) == sorted(own.faces.tolist()) and cap.name in [c.name for c in caps]
    assert caps_on(fine, fine, caps) is caps and caps_on(coarse, fine, None) is None
    assert isinstance(wall_projector(coarse, on, kept=[c.id for c in on]), CapKeepingProjector)


def test_a_cap_touched_by_a_thinner_vessel_keeps_that_vessels_points():
    """A cap cut through a passing vessel much thinner than itself (s0 g0015 extracted: cap
    radius 1.27, the passing vessel 0.34) has all of that vessel's lumen within a quarter of
    the cap's radius of the wall: judged by the cap's radius, none of its points on the cap
    stayed there, and the boundary layer folded between cap and wall. Judged by the thinner
    vessel's radius (``kept`` maps the cap to it) a point 0.15 in from the rim stays; a
    point a chord's sagitta in still goes to the wall, and a plain id list is the cap's
    own radius as before."""
    from vmesh.geometry.projection import keep_radii

    surface, caps = _capped_tube()
    top = max(caps, key=lambda c: c.center[2])
    p = np.array([[0.85, 0.0, 6.0]])  # on the top cap, 0.15 in from the rim
    rim = np.array([[0.99, 0.0, 6.0]])
    assert wall_projector(surface, caps, kept=[top.id]).project(p)[2][0] >= 0  # 0.15 < 0.25 x 1: to the wall
    thin = wall_projector(surface, caps, kept={top.id: 0.3})
    closest, _, face = thin.project(p)
    assert face[0] == ON_CAP and np.allclose(closest, p)
    assert thin.project(rim)[2][0] >= 0
    assert keep_radii(caps, {top.id: 0.3, 99: 0.1}) == {top.id: 0.3}
    assert keep_radii(caps, {top.id: 5.0}) == {top.id: pytest.approx(top.radius)}  # a thicker vessel: the cap's own radius
    assert keep_radii(caps, [top.id]) == {top.id: pytest.approx(top.radius)}


def test_touched_caps_carry_the_thinnest_vessel_in_contact():
    """``build_block_structure``'s contact cuts name each touched cap with the radius of the
    thinnest vessel in contact at its end (what the wall projector judges its points by)."""
    from types import SimpleNamespace

    from vmesh.filters.block_filters import _contact_cuts

    y = np.arange(-8.0, 4.01, 1.0)
    thick = np.stack([np.zeros(9), y[:9], np.zeros(9)], 1)
    thin = np.stack([np.full(len(y), 0.9), y, np.zeros(len(y))], 1)
    points = np.r_[thick, thin]
    radii = np.r_[np.full(9, 1.0), np.full(len(y), 0.3)]
    edges = np.r_[np.stack([np.arange(8), np.arange(1, 9)], 1), 9 + np.stack([np.arange(len(y) - 1), np.arange(1, len(y))], 1)]
    sk = SimpleNamespace(points=points, radii=radii, edges=edges, endpoints=np.array([0, 8, 9, 9 + len(y) - 1]))
    cap = SimpleNamespace(id=2, center=np.array([0.0, 0.0, 0.0]), normal=np.array([0.0, 1.0, 0.0]), radius=1.0, name="outlet_1")
    cuts, touched = _contact_cuts(sk, np.array([[8, 17, -0.55]]), [cap], 1.0)
    assert cuts is not None and touched == {2: pytest.approx(0.3)}


def test_the_rays_territory_ends_at_a_touched_open_end():
    """A thick tube (radius 1) along y ending open at y = 0 (its cap touched by a passing
    vessel), a ray from the passing vessel's axis (x = 1.8) straight at the thick axis: at
    y = -2 it is cut where it enters the thick tube, as before; at y = +0.5, past the cap's
    plane where the thick vessel no longer is, the thick tube's end spheres reach it still
    but its territory ends there (``ended_at_touched_caps``); an untouched cap ends nothing."""
    from types import SimpleNamespace

    from vmesh.geometry.blocks.ended import ended_at_touched_caps
    from vmesh.geometry.blocks.prep import branch_tubes
    from vmesh.geometry.rays import clip_to_territory

    pos = np.c_[np.zeros(9), np.arange(-8.0, 0.01, 1.0), np.zeros(9)]  # thick axis, end node 8 at y = 0
    radii = np.ones(9)
    branch = SimpleNamespace(nodes=np.arange(9))
    Q, rq, q_node, _ = branch_tubes([branch], pos, radii)
    ter = SimpleNamespace(Q=Q, q_node=q_node)
    topo = SimpleNamespace(branches=[branch], pos=pos, sk=SimpleNamespace(radii=radii))
    cap = SimpleNamespace(id=2, center=np.zeros(3), normal=np.array([0.0, 1.0, 0.0]), radius=1.0)
    ended = ended_at_touched_caps(ter, topo, {8: cap}, (2,))
    assert ended_at_touched_caps(ter, topo, {8: cap}, ()) is None and ended_at_touched_caps(ter, topo, {8: cap}, (5,)) is None
    origins = np.array([[1.8, -2.0, 0.0], [1.8, 0.5, 0.0]])
    dirs = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    lengths = np.array([2.8, 2.8])
    every = lambda r, q: np.ones(len(r), bool)  # noqa: E731
    plain = clip_to_territory(origins, dirs, lengths, np.full(2, 0.45), every, (Q, rq))
    out = clip_to_territory(origins, dirs, lengths, np.full(2, 0.45), every, (Q, rq), ended=ended)
    assert plain[0] < 1.5 and plain[1] < 1.5  # both cut: the end spheres reach past the plane
    assert out[0] == pytest.approx(plain[0]) and out[1] == pytest.approx(2.8)
