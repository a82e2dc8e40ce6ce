"""Open ends' sections whose rays come out short (``build_block_structure.short_end_rays``,
docs/optimiser.md h23/minima): a flat closed end on a voxel staircase surface, which the
cleaning takes for wall, leaves the end's section in the end's own plane."""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np

from data_synthetic.vessel_generator import Vessel, finish_surface, tag_ends, write_vessel
from data_synthetic.vessels import surface as S
from data_synthetic.vessels import tree as T


def staircase_tube(folder, radius: float = 0.65, length: float = 8.0, grid: float = 0.207, direction=(1.0, 0.35, 0.2)) -> dict:
    """A straight tube at a slant to the voxel grid, closed by flat ends and contoured as a
    staircase (not smoothed), as the generator makes a ``staircase`` vessel with flat ends
    (s1 g0010: grid 0.207, outlets of radius 0.63-0.67). Writes the vessel's files into
    ``folder`` (its true centerline ends in the ends' planes); returns its manifest."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    tree = T.Tree()
    tree.branches.append(T.Branch(*T.straight(np.zeros(3), length * d, radius, radius)))
    xyz, rad, tags, edges = T.skeleton_of(tree)
    caps = [(e, n, r) for _, e, n, r in S.end_caps(tree)]
    tag_ends(tree, xyz, tags, caps)
    F, grid_ = S.implicit_field(tree, "flat", grid)
    V, Tri = finish_surface(*S.contour(F, grid_, True, smooth_iters=0), caps, "flat", True)
    return write_vessel(Vessel(V, Tri, xyz, rad, tags, edges, {"name": "staircase_tube", "units": "mm", "surface_format": "vtp"}), Path(folder))


def test_end_sections_cut_short_by_a_staircase_end_move_back(tmp_path):
    """The cleaning takes the staircase's flat regions, the ends' too, for wall facets, so both
    ends are open ends without a cap and their sections stand in the ends' planes, where the
    terraces cut their rays short (with ``short_end_rays = 0``: 21 inverted elements, least -0.288, in
    the boundary layer of the two end segments). With ``short_end_rays = 0.5`` (the default) both end
    sections move half a segment back: every element valid and above 0.5, no part of the
    wall missing (what lies past the moved sections is within the ends' depth)."""
    from vmesh.chain import FilterChain
    from vmesh.geometry.quality import scaled_jacobian
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    staircase_tube(tmp_path)
    chain = FilterChain.load("default").with_overrides({"compute_quality.fail_on_invalid": False})  # short_end_rays 0.5 by default
    ctx = chain.run(surface=read_surface(glob.glob(str(tmp_path / "surface.*"))[0]), skeleton=read_skeleton(tmp_path / "centerline.vtp"))
    assert not ctx.caps  # the condition under test: no end is a cap
    q = scaled_jacobian(ctx.mesh.points, ctx.mesh.cells, ctx.mesh.order)
    assert q.min() > 0.5 and q.mean() > 0.9
    coverage = ctx.report.sections["coverage"]
    assert coverage["missing_parts"] == 0 and coverage["uncovered_share"] < 0.01
