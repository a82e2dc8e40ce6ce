"""Cross-sections with a notch (a short ray on a core diagonal): the core stays convex.

Found on hepatic_artery extracted (issue 17, 2026-12-04): a vessel of radius 0.14-0.25 on a
coarse surface (below the extraction's voxel size) has lumpy sections whose diagonal ray is
less than half its axis rays. The core quadrant's corner then fell inside the chord between
its axis points (a dart) and two core blocks stayed invalid in every try of the builder,
however far the core shrank. The regression vessel: a straight tube with a groove along it.
"""

from __future__ import annotations

import numpy as np
import pytest

from vmesh.geometry import cross_sections as cs
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.skeleton import Skeleton


def _quad_areas(t, V) -> np.ndarray:
    """Signed areas (in the section plane) of the core quads' corner triangles, (nq, 4)."""
    q = t.quads[t.quad_layer == cs.LAYER_CORE]
    P = V[q][..., :2]
    a, b, c = np.roll(P, 1, axis=1), P, np.roll(P, -1, axis=1)
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - b[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - b[..., 0])


def _section(t, lengths):
    e1, e2 = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])
    return cs.section_vertices(t, np.zeros((1, 3)), e1, e2, lengths[None], 0.35, 0.25)[0]


@pytest.mark.parametrize("n", [8, 10, 12])
def test_notched_section_keeps_a_convex_core(n):
    t = cs.o_grid_template(n)
    R = np.ones(len(t.ray_angles))
    diag = np.abs(np.sin(2 * t.ray_angles)) > 0.2  # every ray off the axes
    R[diag] = 0.3  # a notch on every diagonal: 0.3 of the axis rays
    assert np.all(_quad_areas(t, _section(t, R)) > 0)


@pytest.mark.parametrize("n", [8, 10, 12])
@pytest.mark.parametrize("aspect", [1.0, 2.0, 5.0, 10.0])
def test_elliptic_sections_are_unchanged(n, aspect):
    """Every ellipse (aspect up to 10, any orientation) keeps the core it had: the corner
    is pushed out only from notched sections."""
    t = cs.o_grid_template(n)
    for phi in np.radians(np.arange(0, 180, 15)):
        th = t.ray_angles - phi
        R = 1.0 / np.sqrt(np.cos(th) ** 2 + (aspect * np.sin(th)) ** 2)
        V = _section(t, R)
        # the corner as before: along its diagonal ray, unclamped
        core = np.flatnonzero(t.kind == cs.VERTEX_CORE)
        x, y = t.xy[core, 0], t.xy[core, 1]
        w, h = np.abs(x).max(), np.abs(y).max()
        corner = (np.abs(x) == w) & (np.abs(y) == h)
        ang = np.arctan2(np.sign(y[corner]) * h, np.sign(x[corner]) * w)
        rd = R[cs.ray_index(t, ang)]
        assert np.allclose(np.linalg.norm(V[core[corner], :2], axis=1), 0.35 * np.hypot(w, h) * rd)


def _grooved_tube(azimuth: float, depth: float = 0.6, half: float = 6.0):
    """A tube of radius 1 along x with a groove along it at ``azimuth`` degrees: a
    cylinder of radius ``depth`` whose axis lies on the wall, cut out of the tube."""
    c = np.array([np.cos(np.radians(azimuth)), np.sin(np.radians(azimuth))])

    def distance(p):
        p = np.asarray(p, float).reshape(-1, 3)
        f = np.minimum(1.0 - np.hypot(p[:, 1], p[:, 2]), half + 1.0 - np.abs(p[:, 0]))
        return np.minimum(f, np.hypot(p[:, 1] - c[0], p[:, 2] - c[1]) - depth)

    x = np.linspace(-half, half, 16)
    sk = Skeleton(np.c_[x, np.zeros((len(x), 2))], np.ones(len(x)), np.c_[np.arange(15), np.arange(1, 16)])
    return sk, distance


@pytest.mark.parametrize("azimuth", [45.0, 52.5, 127.5])
def test_grooved_tube_blocks_valid(azimuth):
    """A groove 0.6 radii deep on a core diagonal of the sections (before: 15 core blocks
    invalid after 67 fixes, corner Jacobian -0.0024)."""
    sk, distance = _grooved_tube(azimuth)
    blocks = build_blocks(sk, distance, None, BlockOptions())
    assert blocks.corner_jacobians().min() > 0
