"""Side stubs the extraction pruned as spurs (issue 17/18: seed 0 g0005, seed 1 g0009, g0013,
g0015 extracted, a whole stub left out of the mesh, named by ``check_coverage``).

A stub of about 0.4 of its parent's radius standing one or two of its own radii out scores
under ``spur_ratio`` (its tip ball barely leaves the junction's). A spur candidate is now
kept when it alone explains wall that the coverage verdict would call missing
(``skeleton.spur_wall``, the verdict's rule ``coverage.judge_patches``); the medial axis's
fans towards a flat end face's rim explain only wall past the rest's free end, which the
vessel's end reaches, and are still pruned."""

from __future__ import annotations

import numpy as np
import pytest

from test_spur_ends import closed_cylinder
from vmesh.geometry.skeleton.extract import ExtractionSettings, extract_skeleton

R, STUB = 1.0, 0.4  # the parent's and the stub's radius
BOX = ([-6.5, -1.5, -1.5], [6.5, 2.5, 1.5])


def stub_sdf(out: float = 1.5):
    """A tube of radius ``R`` along x (-6 to 6, flat closed ends) and a stub of radius
    ``STUB`` along +y from its axis, its rounded end ``out`` of its radii past the wall."""
    tip = R + out * STUB - STUB

    def sdf(p):
        p = np.asarray(p, float).reshape(-1, 3)
        tube = closed_cylinder(p, [-6.0, 0, 0], [6.0, 0, 0], R)
        seg = np.clip(p[:, 1], 0.0, tip)
        capsule = STUB - np.linalg.norm(p - np.c_[np.zeros(len(p)), seg, np.zeros(len(p))], axis=1)
        return np.maximum(tube, capsule)

    return sdf


def wall_of(sdf, lo, hi, h=0.1):
    """The zero level set of ``sdf`` (marching cubes on a grid of step ``h``)."""
    from skimage.measure import marching_cubes

    axes = [np.arange(a - 2 * h, b + 2 * h, h) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = sdf(grid.reshape(-1, 3)).reshape(grid.shape[:3])
    verts, faces, _, _ = marching_cubes(values, 0.0, spacing=(h, h, h))
    return verts + np.array([a[0] for a in axes]), faces[:, ::-1]


@pytest.mark.parametrize("spur_wall", [True, False])
def test_a_stub_standing_out_of_its_parent_keeps_its_branch(spur_wall):
    sdf = stub_sdf()
    skeleton, stats = extract_skeleton(
        sdf, BOX, min_radius=STUB, surface=wall_of(sdf, *BOX), settings=ExtractionSettings(spur_wall=spur_wall)
    )
    ends = skeleton.points[skeleton.degrees == 1]
    on_stub = ends[ends[:, 1] > R]
    if not spur_wall:  # as before: pruned (tip ball 1.8 junction radii out)
        assert len(on_stub) == 0 and stats["spurs"] >= 1
        return
    # the stub's end inside its rounded end, on its axis; the tube's two ends besides
    assert len(on_stub) == 1 and len(ends) == 3, ends
    assert R + 0.2 * STUB < on_stub[0, 1] < R + 1.5 * STUB and np.hypot(on_stub[0, 0], on_stub[0, 2]) < 0.3 * STUB


def _fan_graph():
    """A tube's axis from x = -5 to J at x = 5, a radius before its flat end face (x = 6),
    and the medial axis's fan from J towards the face's rim: three branches along the cone
    of points as far from the face as from the side wall (radius 1 - s at (5 + s, s, 0))."""
    from vmesh.geometry.skeleton.branch_graph import BranchGraph

    graph = BranchGraph()
    a, j = graph.add_node([-5.0, 0, 0], R), graph.add_node([5.0, 0, 0], R)
    x = np.arange(-4.9, 5.0, 0.1)
    graph.add_branch(a, j, np.c_[x, np.zeros((len(x), 2))], np.full(len(x), R))
    spurs = []
    for angle in (0.0, 2.1, 4.2):
        s = np.arange(0.1, 0.85, 0.1)
        pts = np.c_[5.0 + s, s * np.cos(angle), s * np.sin(angle)]
        tip = graph.add_node(pts[-1], R - s[-1])
        key = graph.add_branch(j, tip, pts[:-1], R - s[:-1])
        spurs.append((j, tip, key, tip, j))
    return graph, spurs


def test_the_fans_towards_a_flat_ends_rim_are_still_pruned(monkeypatch):
    """The wall the fan alone explains is the rim's, past the rest's free end (J, once the
    fan is gone), which the vessel's end reaches (place_ends): judged with the verdict's
    end depth it is no missing part; judged as a side wall it would be (the scratch rule of
    session 18 held such fans and broke the builder)."""
    from vmesh.geometry.skeleton import spur_wall
    from vmesh.geometry.skeleton.spur_wall import spurs_explaining_wall, surface_samples

    sdf = lambda p: closed_cylinder(np.asarray(p, float).reshape(-1, 3), [-6.0, 0, 0], [6.0, 0, 0], R)  # noqa: E731
    wall = surface_samples(*wall_of(sdf, [-6.5, -1.5, -1.5], [6.5, 1.5, 1.5]))
    graph, spurs = _fan_graph()
    details = []
    assert not spurs_explaining_wall(graph, wall, spurs, 0.1, details=details).any()
    assert all(d["at_end"] and d["depth_rel"] > 0.3 for d in details)  # rim wall outside the rest's balls
    # judged as side wall (no free end), by the fan's own small radius: held
    monkeypatch.setattr(spur_wall, "_free_ends", lambda graph, spurs: (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))))
    assert spurs_explaining_wall(graph, wall, spurs, 0.1).all()


@pytest.mark.slow
def test_a_generated_stub_extracted_and_meshed_is_covered(tmp_path):
    """The generator's stub (radius 0.4 of its parent's, rounded end 1.5 of its radii past
    the wall), its skeleton extracted: the stub is in the skeleton, the mesh valid and the
    coverage check passes (before: the stub's branch pruned, a missing part named)."""
    from data_synthetic.vessel_generator import stub_vessel, write_vessel
    from vmesh.chain import FilterChain

    m = write_vessel(stub_vessel(90, 0.4, 1.5, end_style="round"), tmp_path / "v")
    chain = FilterChain.load("default")
    chain.steps = [s for s in chain.steps if not s.filter.startswith("write")]
    ctx = chain.run(surface=tmp_path / "v" / m["files"]["surface"])
    ends = ctx.skeleton.points[ctx.skeleton.degrees == 1]
    assert (ends[:, 1] > 1.0).sum() == 1
    assert ctx.report.sections["quality"]["scaled_jacobian"]["min"] >= 0.3
    assert ctx.report.sections["coverage"]["missing_parts"] == 0
