"""The folds the optimiser cannot lift are handed to the block structure: the builder lists the
boundary-layer blocks whose wall faces fold when projected onto the wall, and
``compute_quality`` says whether the mesh's worst elements lie in them (docs/optimiser.md,
issue 17 + 18, 2026-12-04)."""

from pathlib import Path

import numpy as np
import pytest

from vmesh.errors import MeshingError
from vmesh.filters.mesh_filters import wall_fold_share


def test_wall_fold_share_splits_the_minimum_at_the_flagged_blocks():
    sj = np.array([0.9, -0.2, 0.1, 0.8, 0.05, 0.7])
    block = np.array([0, 1, 1, 2, 3, 3])
    out = wall_fold_share(sj, block, [1])
    assert out == {"blocks": 1, "elements": 2, "min_inside": -0.2, "min_elsewhere": 0.05, "invalid_inside": 1}
    assert wall_fold_share(sj, block, []) is None and wall_fold_share(sj, block, None) is None
    # a flagged block may hold no element of the mesh (ids beyond the mesh's are fine)
    assert wall_fold_share(sj, block, [7])["elements"] == 0


@pytest.mark.slow
def test_a_cap_through_a_thin_passing_vessel_keeps_its_layer_valid(tmp_path):
    """Generated g0015 (seed 0, preset mixed), its skeleton extracted: a thin vessel (radius
    0.30-0.45) passes the open end of a thick one (cap radius 1.27) whose cap, capped whole
    (no centerline to split the rim's window by), crosses the thin lumen. The wall projector
    kept a point on that cap only 0.32 (a quarter of the cap's radius) from the wall, i.e.
    nowhere in the thin lumen: the layer folded between cap and wall (raw fill 73 inverted,
    final 32 at -0.505). Judged by the thin vessel's radius (``touched_caps`` maps the cap
    to it) and the section rays' territory ended at that cap's plane (as the contact cut
    is), every element of the raw fill, before any untangling, is valid (docs/optimiser.md,
    h25/inverted)."""
    from data_synthetic.vessel_generator import generate_one

    from test_mesh_cases import run_default

    m = generate_one(tmp_path, 15, 0, "mixed")
    ctx = run_default(str(Path(m["folder"]) / m["files"]["surface"]), **{"compute_quality.fail_on_invalid": False, "mesh_transfinite.untangle": False})
    touched = ctx.blocks.info["touched_caps"]
    radius = {c.id: c.radius for c in ctx.caps}
    assert touched and all(r < radius[k] for k, r in touched.items())  # judged by the thinner vessel
    assert (ctx.mesh.cell_data["scaled_jacobian"] > 0).all()


@pytest.mark.slow
def test_a_fold_at_two_overlapping_junctions_is_named_as_the_block_structures(tmp_path):
    """Generated g0016 (seed 1, preset mixed), its skeleton extracted: junctions 3 and 4 with
    overlapping balls; the builder moves junction 3 away from 4 (``separate_junctions``) to
    make the link's blocks valid, and the blocks of its other branch there fold once their
    wall faces are projected (docs/junctions.md, h25/inverted). Elements stay inverted
    there; most of them lie in the blocks the builder flagged, and the error says so."""
    from data_synthetic.vessel_generator import generate_one

    from test_mesh_cases import run_default
    from vmesh.registry import get_filter

    m = generate_one(tmp_path, 16, 1, "mixed")
    ctx = run_default(str(Path(m["folder"]) / m["files"]["surface"]), **{"compute_quality.fail_on_invalid": False})
    folds = ctx.report.sections["quality"]["wall_fold_blocks"]
    sj = ctx.mesh.cell_data["scaled_jacobian"]
    assert 2 * folds["invalid_inside"] > int((sj <= 0).sum()) > 0
    assert folds["min_inside"] < 0 < folds["elements"]
    with pytest.raises(MeshingError, match="found folding when their wall faces are projected"):
        get_filter("compute_quality")(ctx, histogram="", fail_on_invalid=True)


@pytest.mark.slow
def test_a_junction_moved_apart_takes_along_the_next_node_it_would_reach(tmp_path):
    """Generated g0016 (seed 1, preset mixed), its skeleton extracted: junction 3, moved
    1.82 away from the overlapping junction 4 (``separate_junctions``), came within 0.40
    of node 54, the next node of its other branch, whose first segment became a stub
    inside the half-sections: 180 of the raw fill's 245 inverted elements lay in that
    segment, next to node 54. With ``carry_next_nodes`` the node moves along: no element
    next to a carried node is inverted in the raw fill (before untangling). The fold of
    the long first column over the saddle beside it stays (docs/junctions.md h26/pair)."""
    import re

    from data_synthetic.vessel_generator import generate_one

    from test_mesh_cases import run_default

    m = generate_one(tmp_path, 16, 1, "mixed")
    ctx = run_default(str(Path(m["folder"]) / m["files"]["surface"]),
                      **{"compute_quality.fail_on_invalid": False, "mesh_transfinite.untangle": False,
                         "build_block_structure.carry_next_nodes": True})
    carried = [int(n) for fix in ctx.blocks.info["fixes"] for found in re.findall(r"taking along its next node\(s\) \[([\d, ]+)\]", fix)
               for n in found.split(",")]
    assert carried
    sj = ctx.mesh.cell_data["scaled_jacobian"]
    node = ctx.mesh.cell_data["node_id"]
    assert not np.any((sj <= 0) & np.isin(node, carried))
