"""Regular cross-sections centred on the middle of the lumen they cut (issue 17, session 25,
branch h25/realbuild; :mod:`vmesh.geometry.blocks.centring`, opt-in
``build_block_structure.centre_sections``).

A skeleton that wanders over a flattened lumen's wide side tilts its sections, whose rays
reach the wide side's walls, so far that neighbours cross inside the lumen: the blocks
between them stay invalid (the builder alone) or the sections miss the wide side's wall
(the default chain: coverage fails). The generated vessel is an elliptic tube (half-axes
10 and 4.5) with a skeleton (radius 3: the thin side) zigzagging 5 either side of the axis
at nodes 3.3-5.6 apart."""

import numpy as np
import pytest

from flat_vessels import flat_tube_case, flat_tube_vessel
from test_dent_sections import DEFAULT
from vmesh.errors import MeshingError
from vmesh.geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
from vmesh.geometry.blocks.centring import chord_offsets
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import mesh_blocks

SHARE = 0.1  # the share of the rays' mean reach off the middle that moves a node


def test_chord_offsets_find_a_round_sections_centre():
    """From a point off a circle's centre the chords' middles give the offset exactly."""
    ang = 2 * np.pi * np.arange(8) / 8
    centre, radius = np.array([0.3, -0.45]), 2.0
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    b = u @ -centre  # rays from the origin to the circle |x - centre| = radius
    R = -b + np.sqrt(b * b - (centre @ centre - radius**2))
    assert np.allclose(chord_offsets(R[None], ang)[0], centre)


def test_a_wandering_skeleton_in_a_flattened_lumen_fails_without_centring():
    # duplicates: the shape of test_bend_sections' fails-without / valid-with pair, on another vessel and option
    case, sk = flat_tube_case()
    assert case.distance(sk.points).min() > 2.0  # every node well inside
    with pytest.raises(MeshingError, match="stay invalid"):
        build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0), project=case.project)


def test_centred_sections_give_valid_blocks_and_elements():
    case, sk = flat_tube_case()
    blocks = build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0, centre_sections=SHARE), project=case.project)
    checks = block_structure_checks(blocks)
    assert checks["invalid_blocks"] == checks["face_use_errors"] == 0
    assert blocks.corner_jacobians().min() > 0
    assert any("centred on their chords' middle" in f for f in blocks.info["fixes"])
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    sj = scaled_jacobian(sm.points, sm.cells, 1)
    assert sj.min() > 0
    # the mesh spans the skeleton's whole length and both sides of the wide lumen
    assert sm.points[:, 0].min() <= sk.points[0, 0] + 1e-6 and sm.points[:, 0].max() >= sk.points[-1, 0] - 1e-6
    assert sm.points[:, 1].min() < -0.95 * case.wide and sm.points[:, 1].max() > 0.95 * case.wide


def test_centring_moves_only_lopsided_sections():
    """On a skeleton on the axis nothing moves (``topo.pos`` stays the skeleton's)."""
    from vmesh.geometry.blocks.builder import _Builder
    from vmesh.geometry.blocks.work import WorkBudget

    case, sk = flat_tube_case(offsets=(0.0, 0.0, 0.0, 0.0))
    b = _Builder(sk, case.distance, None, BlockOptions(dent_sections=0, centre_sections=SHARE), None, None, work=WorkBudget(160))
    b.make_valid()
    assert np.array_equal(b.topo.pos, sk.points)
    assert not any("centred" in f for f in b.fixes)


def test_centring_builds_the_winding_skeleton_of_a_round_tube():
    """Session 24's bend vessel (:mod:`test_bend_sections`: a tube of radius 10, a skeleton
    of radius 3 turning 29-36 degrees at nodes 3.3-5.6 apart) builds with its nodes
    centred, no node dropped."""
    from test_bend_sections import winding_skeleton

    case, sk = winding_skeleton()
    blocks = build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0, centre_sections=SHARE), project=case.project)
    assert block_structure_checks(blocks)["invalid_blocks"] == 0
    assert blocks.info["skeleton"].n_nodes == sk.n_nodes
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    assert scaled_jacobian(sm.points, sm.cells, 1).min() > 0


@pytest.mark.slow
def test_the_default_chain_covers_the_flattened_vessel_with_centring(tmp_path):
    """The default chain on the tube's surface with its given skeleton: without centring the
    sections miss the wide side's wall (coverage fails: 1.2 % of the wall, 4 parts); with it
    the mesh is valid and covers the wall."""
    from test_mesh_cases import check_mesh, run_default
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    m = flat_tube_vessel(tmp_path)
    surface = read_surface(tmp_path / m["files"]["surface"])
    skeleton = read_skeleton(tmp_path / m["files"]["skeleton_json"])
    with pytest.raises(MeshingError, match="leaves out part of the vessel"):
        run_default(surface, skeleton)
    ctx = run_default(surface, skeleton, **{"build_block_structure.centre_sections": SHARE})
    sj = check_mesh(ctx)
    assert sj.min() > 0
    assert ctx.report.sections["coverage"]["uncovered_share"] == 0.0
