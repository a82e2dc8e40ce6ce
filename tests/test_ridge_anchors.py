"""A short side stub that the distance-ordered thinning peels as a bump gets a branch when
the thinning is anchored at the flat ridges of the distance the skeleton's balls leave out
(``extract_skeleton.ridge_slope``, opt-in; docs/coverage.md h26/pair)."""

import json
from pathlib import Path

import numpy as np
import pytest

import vmesh
from vmesh.geometry.skeleton import thin as th


def test_flat_ridge_voxels_are_a_tubes_axis_not_its_sides():
    """Along a tube's axis the distance is flat (kept), off it it falls one for one (not)."""
    shape = (9, 9, 20)
    idx = np.indices(shape).reshape(3, -1).T.astype(float)
    radial = 3.2 - np.hypot(idx[:, 0] - 4, idx[:, 1] - 4)
    mask = (radial > 0).reshape(shape)
    mask[:, :, 0] = mask[:, :, -1] = False
    distance = radial.reshape(shape)[mask]
    ridge = th.flat_ridge_voxels(mask, distance, 0.5, 1.0)
    ijk = np.argwhere(mask)[ridge]
    assert len(ijk) and np.all((ijk[:, 0] == 4) & (ijk[:, 1] == 4))


def test_anchors_only_beside_the_skeleton_where_its_balls_leave_the_ridge_out():
    """A bar (5 x 5 voxels) with a side bar (3 x 3) leaving its middle: with the skeleton
    along the bar only, the side bar's ridge gets one anchor; with the side bar's axis in
    the skeleton, none; past a curve end (the vessel's own end), none either."""
    mask = np.zeros((14, 7, 22), bool)
    mask[1:6, 1:6, 1:21] = True
    mask[6:13, 2:5, 10:13] = True
    idx = np.argwhere(mask).astype(float)
    bar = np.minimum.reduce([idx[:, 0] - 0.5, 5.5 - idx[:, 0], idx[:, 1] - 0.5, 5.5 - idx[:, 1], idx[:, 2] - 0.5, 20.5 - idx[:, 2]])
    side = np.minimum.reduce([idx[:, 0] - 0.5, 12.5 - idx[:, 0], idx[:, 1] - 1.5, 4.5 - idx[:, 1], idx[:, 2] - 9.5, 12.5 - idx[:, 2]])
    distance = np.maximum(bar, side)
    ridge = th.flat_ridge_voxels(mask, distance, 0.5, 1.0)
    thin = np.zeros_like(mask)
    thin[3, 3, 2:20] = True
    anchors = th.unexplained_ridge_anchors(mask, distance, thin, ridge)
    assert anchors.sum() == 1 and np.argwhere(mask)[anchors][0, 0] >= 8
    thin[3:12, 3, 11] = True
    assert not th.unexplained_ridge_anchors(mask, distance, thin, ridge).any()
    thin[:, :, :] = False
    thin[3, 3, 2:6] = True  # the skeleton stops short of the bar's end: that end is the end placement's
    assert not th.unexplained_ridge_anchors(mask, distance, thin, ridge).any()


@pytest.mark.slow
def test_a_stub_peeled_by_the_thinning_gets_a_branch_with_ridge_anchors(tmp_path):
    """Generated g0010 (seed 0, preset mixed): a stub (radius 0.034 on a parent of 0.083,
    flat end 1.6 of its radii past the parent's wall, 2.4 voxels in radius) has no branch:
    the distance rises monotonically from its end into the parent, the thinning peels it,
    and check_coverage fails on it. With ``ridge_slope`` the extracted skeleton ends in it."""
    from data_synthetic.vessel_generator import generate_one

    m = generate_one(tmp_path, 10, 0, "mixed")
    folder = Path(m["folder"])
    nodes = json.loads((folder / "skeleton.json").read_text())["nodes"]
    stub_end = np.array(next(n["xyz"] for n in nodes if "stub" in n["tags"] and "outlet" in n["tags"]))
    stub_r = next(n["radius"] for n in nodes if "stub" in n["tags"])
    ends = {}
    for slope in (0.0, 0.5):
        chain = vmesh.FilterChain.load("default").with_overrides({"extract_skeleton.ridge_slope": slope})
        names = [s.filter for s in chain.steps]
        chain.steps = chain.steps[: names.index("resample_skeleton") + 1]
        sk = chain.run(surface=str(folder / m["files"]["surface"]), skeleton=None).skeleton
        ends[slope] = float(np.min(np.linalg.norm(sk.points[sk.endpoints] - stub_end, axis=1)))
    assert ends[0.0] > 3 * stub_r  # the cause: no end in the stub
    assert ends[0.5] < stub_r
