"""Valid but poor blocks lifted by the invalid-block repairs (``build_block_structure.poor_block_sj``,
:mod:`vmesh.geometry.blocks.poor`, docs/optimiser.md h24/minima)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vmesh.geometry.blocks.poor import block_scaled_jacobians, shortfall

TRIFURCATION = Path(__file__).resolve().parents[1] / "data_synthetic" / "trifurcation" / "surface.ply"


def test_shortfall_counts_only_what_lies_below_the_floor():
    assert shortfall(np.array([0.1, 0.25, 0.3, 0.9]), 0.3) == pytest.approx(0.25)
    assert shortfall(np.array([0.5, 0.9]), 0.3) == 0.0


def test_block_scaled_jacobians_of_a_unit_cube_and_a_sheared_one():
    from types import SimpleNamespace

    from vmesh.blocks import HEX_CORNERS

    cube = HEX_CORNERS.astype(float)
    sheared = cube.copy()
    sheared[:, 0] += 0.9 * sheared[:, 2]  # x leans with z: every corner's scaled Jacobian is 1 / sqrt(1 + 0.81)
    blocks = SimpleNamespace(vertices=np.vstack([cube, sheared + 5.0]), hexes=np.vstack([np.arange(8), np.arange(8, 16)]))
    sj = block_scaled_jacobians(blocks)
    assert sj[0] == pytest.approx(1.0)
    assert sj[1] == pytest.approx(1.0 / np.sqrt(1.81))


@pytest.mark.slow
def test_poor_trifurcation_blocks_are_lifted_above_the_bar():
    """The bundled trifurcation, skeleton extracted: its first valid blocks hold a junction
    block whose least corner scaled Jacobian is 0.001 (0.039 at best after the builder's
    other steps without the lift) and the mesh's worst element ends at 0.293. With
    ``poor_block_sj = 0.3`` the poor junction ends are repaired segment by segment: every
    block valid, no block below 0.03, and every element of the mesh above 0.3."""
    from vmesh.chain import FilterChain
    from vmesh.geometry.quality import scaled_jacobian
    from vmesh.io.surface import read_surface

    chain = FilterChain.load("default").with_overrides({"build_block_structure.poor_block_sj": 0.3, "compute_quality.fail_on_invalid": False})
    ctx = chain.run(surface=read_surface(TRIFURCATION))
    blocks = ctx.blocks
    assert blocks.corner_jacobians().min() > 0
    assert block_scaled_jacobians(blocks).min() > 0.03
    assert any(f.startswith("lifted poor blocks") for f in blocks.info["fixes"])
    q = scaled_jacobian(ctx.mesh.points, ctx.mesh.cells, ctx.mesh.order)
    assert q.min() > 0.3 and q.mean() > 0.9
    assert ctx.report.sections["coverage"]["missing_parts"] == 0


def test_moved_blocks_names_only_the_blocks_whose_corners_moved():
    """A lift trial is judged by the blocks it moved: one section of a hand-built cylinder
    moved along the axis moves the blocks on both sides of it, and none else; structures of
    other blocks are not compared."""
    from cylinder_blocks import cylinder_blocks

    from vmesh.geometry.blocks.poor import moved_blocks

    before = cylinder_blocks(sections=5)
    after = cylinder_blocks(sections=5)
    assert len(moved_blocks(before, after)) == 0
    after.vertices[2 * 25:3 * 25, 2] += 0.5  # the third section (25 corners) moves along z
    moved = moved_blocks(before, after)
    assert sorted(set(before.block_segment[moved].tolist())) == [1, 2]
    assert len(moved) == 2 * 20  # both segments' 4 core, 8 ring and 8 layer blocks
    assert moved_blocks(before, cylinder_blocks(sections=4)) is None


def test_fill_summary_of_a_straight_cylinder_is_valid_at_every_resolution():
    """The raw fill the lift's trial log records (least and mean element per resolution):
    a straight O-grid cylinder fills validly (least > 0.3, mean > 0.8) at the default chain's
    and the finer resolution, and a section leaned (its blocks sheared) fills
    worse than it did."""
    from cylinder_blocks import cylinder_blocks, project_cylinder

    from vmesh.geometry.blocks.checks import FILL_CHECKS
    from vmesh.geometry.blocks.poor import fill_summary

    blocks = cylinder_blocks(radius=2.0, length=10.0, sections=5)
    project = project_cylinder(2.0)

    def distance(p):
        return 2.0 - np.linalg.norm(np.asarray(p)[:, :2], axis=1)

    every = np.arange(blocks.n_blocks)
    good = fill_summary(blocks, every, project, distance)
    assert good.shape == (len(FILL_CHECKS), 2)
    assert np.all(good[:, 0] > 0.3) and np.all(good[:, 1] > 0.8)
    tilted = cylinder_blocks(radius=2.0, length=10.0, sections=5)
    sec = slice(2 * 25, 3 * 25)
    tilted.vertices[sec, 2] += 0.9 * tilted.vertices[sec, 0]  # the third section leans: its blocks shear
    worse = fill_summary(tilted, every, project, distance)
    assert np.all(worse[:, 0] < good[:, 0]) and np.all(worse[:, 1] < good[:, 1])


def test_optimised_summary_lifts_a_sheared_section_but_holds_the_faces_it_shares():
    """The optimised judge (``poor_block_optimised``): the blocks filled at the default
    resolution and optimised as ``mesh_transfinite`` does, with the blocks around them
    free. A straight O-grid cylinder stays as good as its raw fill; a leaned section's
    blocks (raw least 0.44) are lifted well above their raw fill, every element valid; the
    blocks of the two segments beside the lean, judged alone with their neighbours
    optimised with them (only the neighbours' outer faces held), end valid and no higher
    than the whole."""
    from cylinder_blocks import cylinder_blocks, project_cylinder

    from vmesh.geometry.blocks.poor import fill_summary, optimised_summary

    project = project_cylinder(2.0)

    def distance(p):
        return 2.0 - np.linalg.norm(np.asarray(p)[:, :2], axis=1)

    blocks = cylinder_blocks(radius=2.0, length=10.0, sections=5)
    every = np.arange(blocks.n_blocks)
    raw = fill_summary(blocks, every, project, distance)[0]
    least, mean = optimised_summary(blocks, every, project, distance)
    assert least >= raw[0] - 1e-9 and mean >= raw[1] - 1e-9
    tilted = cylinder_blocks(radius=2.0, length=10.0, sections=5)
    sec = slice(2 * 25, 3 * 25)
    tilted.vertices[sec, 2] += 0.9 * tilted.vertices[sec, 0]
    raw = fill_summary(tilted, every, project, distance)[0]
    whole = optimised_summary(tilted, every, project, distance)
    assert whole[0] > raw[0] + 0.1 and whole[1] > raw[1] - 1e-9
    beside = np.flatnonzero(np.isin(tilted.block_segment, [1, 2]))
    part = optimised_summary(tilted, beside, project, distance)
    assert 0 < part[0] <= whole[0] + 1e-9
    assert optimised_summary(tilted, np.array([], np.int64), project, distance) == (-np.inf, -np.inf)
