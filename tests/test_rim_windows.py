"""An open end whose rim takes in a window of a passing vessel's wall (h22/fold, s0 g0015):
with the centerline given, ``cap_open_ends.split_windows`` closes the window as wall and
caps only the end, so no cap crosses the passing vessel's lumen. A short branch whose rim
runs over the wall of the parent it grows out of (h23/windows, s0 g0009, g0007), at any
angle, has no window: its end is capped whole."""

from __future__ import annotations

import glob

import numpy as np
import pytest

from contact_vessels import end_cut_at_parent_wall, end_cut_through_neighbour
from vmesh.chain import FilterChain
from vmesh.geometry import topology
from vmesh.io.skeleton import read_skeleton
from vmesh.io.surface import read_surface
from vmesh.rim_windows import WALL_FIT, split_rim, window_on_passing_branch


@pytest.fixture(scope="module")
def cut_vessel(tmp_path_factory):
    folder = tmp_path_factory.mktemp("end_cut")
    end_cut_through_neighbour(folder)
    return read_surface(glob.glob(str(folder / "surface.*"))[0]), read_skeleton(folder / "skeleton.json")


def _thin_axis_distance(points, skeleton):
    """Distance to the thin branch's axis (radius 0.45) over its radius: the nearest point on its polyline."""
    thin = np.flatnonzero(np.isclose(skeleton.radii, 0.45))
    a, b = skeleton.points[thin[:-1]], skeleton.points[thin[1:]]
    ab = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None] - a[None], ab) / (ab * ab).sum(1), 0, 1)
    return np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1) / 0.45


def test_the_window_is_the_rims_run_on_the_passing_branch(cut_vessel):
    surface, skeleton = cut_vessel
    loops = topology.join_touching(topology.boundary_loops(surface.faces))
    windows = [window_on_passing_branch(surface.vertices[lp], skeleton.points, skeleton.radii, skeleton.edges) for lp in loops]
    assert [int(w.any()) for w in windows].count(1) == 1  # the tube's end only, not the thin branch's own end
    loop, window = next((lp, w) for lp, w in zip(loops, windows) if w.any())
    on_thin = np.abs(_thin_axis_distance(surface.vertices[loop], skeleton) - 1.0) < 0.25
    assert on_thin[window].all() and 3 <= window.sum() <= len(loop) - 3
    chord, end_loop, window_loop = split_rim(surface.vertices, loop, window)
    assert len(end_loop) + len(window_loop) == len(loop) + 2 + 2 * len(chord)  # the chord's ends and points shared
    assert set(end_loop) | set(window_loop) == set(loop) | set(range(len(surface.vertices), len(surface.vertices) + len(chord)))


@pytest.mark.parametrize("split", [False, True])
def test_split_windows_keeps_the_cap_out_of_the_passing_lumen(cut_vessel, split):
    """Without the split the flat cap spans the window: cap vertices deep in the thin lumen.
    With it the surface is closed, the cap stays out of the thin lumen, the window's patch
    lies near the thin branch's wall, and the report names the window."""
    surface, skeleton = cut_vessel
    chain = FilterChain(["repair_surface", ("cap_open_ends", {"split_windows": split})])
    ctx = chain.run(surface=surface, skeleton=skeleton)
    s = ctx.surface
    assert not topology.boundary_loops(s.faces)
    cap = max(ctx.caps, key=lambda c: c.radius)  # the tube's end (radius 1.2); the thin end is 0.45
    cap_vertices = np.unique(s.faces[cap.faces])
    depth = _thin_axis_distance(s.vertices[cap_vertices], skeleton)
    if not split:
        assert depth.min() < 0.5 and "cap_windows" not in ctx.report.sections
        return
    assert depth.min() > 0.7
    assert len(ctx.report.sections["cap_windows"]) == 1
    patch = np.setdiff1d(np.arange(surface.n_vertices, s.n_vertices), np.unique(s.faces[np.concatenate([c.faces for c in ctx.caps])]))  # not on a cap: the window patch
    assert len(patch) and np.abs(_thin_axis_distance(s.vertices[patch], skeleton) - 1.0).max() < 0.5


@pytest.fixture(scope="module", params=[12.0, 20.0, 45.0, 80.0])
def stub_vessel(tmp_path_factory, request):
    """The stub at shallow to steep angles: the shallower, the farther its root lies behind
    its end and the longer its rim's run over the parent's wall."""
    folder = tmp_path_factory.mktemp("stub_cut")
    end_cut_at_parent_wall(folder, angle=request.param)
    return read_surface(glob.glob(str(folder / "surface.*"))[0]), read_skeleton(folder / "skeleton.json")


def test_a_stub_ending_against_its_parent_has_no_window(stub_vessel):
    """The stub's rim runs over the parent tube's wall (radius 1.2 about the x axis), which
    passes the stub's end; the stub grows out of that tube (its root lies on the tube's
    axis), so that is no passing vessel's window, and split_windows caps every end whole:
    the same closed surface as without it."""
    surface, skeleton = stub_vessel
    repaired = FilterChain(["repair_surface"]).run(surface=surface, skeleton=skeleton).surface
    loops = topology.join_touching(topology.boundary_loops(repaired.faces))
    stub_end = max(loops, key=lambda lp: repaired.vertices[lp, 1].mean())  # the stub rises towards +y
    rim = repaired.vertices[stub_end]
    on_parent = np.abs(np.linalg.norm(rim[:, 1:], axis=1) / 1.2 - 1.0) < WALL_FIT
    assert on_parent.sum() >= 3 and (~on_parent).sum() >= 3  # the rim does run over the parent's wall
    for lp in loops:
        assert not window_on_passing_branch(repaired.vertices[lp], skeleton.points, skeleton.radii, skeleton.edges).any()
    capped = [FilterChain(["repair_surface", ("cap_open_ends", {"split_windows": split})]).run(surface=surface, skeleton=skeleton) for split in (False, True)]
    assert not topology.boundary_loops(capped[1].surface.faces) and "cap_windows" not in capped[1].report.sections
    np.testing.assert_array_equal(capped[0].surface.vertices, capped[1].surface.vertices)
    np.testing.assert_array_equal(capped[0].surface.faces, capped[1].surface.faces)


def test_a_stub_given_as_one_segment_has_no_window(stub_vessel):
    """The same stub with its centerline given as one segment, root to tip (a sparse SWC):
    where the path leaves the parent's tube is found between its two nodes, not at its last
    node inside (the root, farther from the rim than the reach at 45 degrees): no window."""
    surface, skeleton = stub_vessel
    repaired = FilterChain(["repair_surface"]).run(surface=surface, skeleton=skeleton).surface
    thin = np.flatnonzero(np.isclose(skeleton.radii, 0.45))
    tip = thin[np.argmax(np.linalg.norm(skeleton.points[thin], axis=1))]
    keep = np.setdiff1d(np.arange(skeleton.n_nodes), np.setdiff1d(thin, [tip]))
    root = keep[np.argmin(np.linalg.norm(skeleton.points[keep], axis=1) + 1e9 * (keep == tip))]
    index = -np.ones(skeleton.n_nodes, np.int64)
    index[keep] = np.arange(len(keep))
    tube = skeleton.edges[(index[skeleton.edges] >= 0).all(axis=1)]
    edges = np.vstack([index[tube], [[index[root], index[tip]]]])
    points, radii = skeleton.points[keep], skeleton.radii[keep]
    assert len(edges) == len(keep) - 1  # still a tree: the tube and the stub's one segment
    for lp in topology.join_touching(topology.boundary_loops(repaired.faces)):
        assert not window_on_passing_branch(repaired.vertices[lp], points, radii, edges).any()


def _warnings_with_meshlab(surface, skeleton):
    ctx = FilterChain(["repair_surface", ("cap_open_ends", {"method": "meshlab"})]).run(surface=surface, skeleton=skeleton)
    assert not topology.boundary_loops(ctx.surface.faces)
    return [w for w in ctx.report.warnings if "split_windows" in w]


def test_meshlab_warns_only_where_a_window_is_left_unsplit(cut_vessel, stub_vessel):
    """split_windows (on) cannot split with method 'meshlab': a warning where an end has a
    window (the cut through the neighbour), none where no end has one (the stub)."""
    assert len(_warnings_with_meshlab(*cut_vessel)) == 1
    assert not _warnings_with_meshlab(*stub_vessel)
