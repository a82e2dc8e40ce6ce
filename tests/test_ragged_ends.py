"""Open ends cut unevenly (issue 17, generated g0013, g0015: ``ragged_ends``).

A hand-cut segmentation's open end has a rim that wanders along the vessel; its cap
(:func:`vmesh.preprocess.cap_loop`) is the cone from that rim to its centroid. In the
cap's plane that cone cuts the lumen short wherever the rim dips behind the plane, so an
end section placed on the plane found the "wall" at a few tenths of the radius there and
the blocks behind it folded. The end section now sits behind the rim's deepest notch
behind the rim's notches at its rays' azimuths
(:meth:`vmesh.geometry.blocks.sections._Sections._behind_notches`).
"""

from __future__ import annotations

import numpy as np
import pytest

from data_synthetic.vessels.surface import ragged_cut
from vmesh import preprocess as pre
from vmesh.blocks import HEX_FACES
from vmesh.geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
from vmesh.geometry.sdf import SignedDistance
from vmesh.skeleton import Skeleton


def cap_recess(cap) -> float:
    """How far the rim of a cap dips behind the cap's plane (0 for a planar rim)."""
    n = np.asarray(cap.normal, float) / np.linalg.norm(cap.normal)
    return float(max(0.0, -np.min((np.asarray(cap.rim) - cap.center) @ n)))


def ragged_tube(seed: int, length: float = 10.0, radius: float = 1.0, depth: float = 0.6):
    """A straight tube along +x (``length``, ``radius``) whose two open ends are cut
    ``depth`` radii deep unevenly around the rim (the generator's ``ragged_cut``), capped as
    ``cap_open_ends`` caps them; its signed distance, caps and a straight skeleton."""
    around, h = 48, 0.1
    x = np.arange(0.0, length + 1e-9, h)
    th = 2 * np.pi * np.arange(around) / around
    V = np.stack([np.repeat(x, around), radius * np.tile(np.cos(th), len(x)), radius * np.tile(np.sin(th), len(x))], axis=1)
    i, j = np.meshgrid(np.arange(len(x) - 1), np.arange(around), indexing="ij")
    a, b = i * around + j, i * around + (j + 1) % around
    c, d = a + around, b + around
    T = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])  # outward
    ends = [(np.array([0.0, 0, 0]), np.array([-1.0, 0, 0]), radius), (np.array([length, 0, 0]), np.array([1.0, 0, 0]), radius)]
    V, T = ragged_cut(V, T, ends, np.random.default_rng(seed), depth)
    V, T, labels = pre.cap_boundary_loops(V, T)
    caps = pre.caps_from_labels(V, T, labels)
    n = int(round(length / (1.25 * radius)))
    P = np.c_[np.linspace(0.0, length, n + 1), np.zeros((n + 1, 2))]
    sk = Skeleton(P, np.full(n + 1, radius), np.c_[np.arange(n), np.arange(1, n + 1)])
    return SignedDistance(V, T), caps, sk


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_end_sections_of_ragged_open_ends_span_the_lumen(seed):
    sdf, caps, sk = ragged_tube(seed)
    assert len(caps) == 2 and max(cap_recess(c) for c in caps) > 0.2  # the rims do dip behind their caps' planes
    blocks = build_blocks(sk, sdf.distance, caps, BlockOptions(), intersect_lines=sdf.intersect_lines)
    checks = block_structure_checks(blocks)
    assert checks["invalid_blocks"] == checks["face_use_errors"] == 0
    for cap in caps:
        # the wall corners of the end face lie on the tube's wall, not on the cap's cone
        b, f = np.nonzero(blocks.face_boundary == cap.id)
        assert len(b) > 0
        ids = np.unique(blocks.hexes[b[:, None], HEX_FACES[f]])
        wall = ids[blocks.vertex_on_surface[ids]]
        radial = np.linalg.norm(blocks.vertices[wall, 1:], axis=1)
        assert radial.min() > 0.9, radial.min()
        # on a plane parallel to the cap's, behind it, not behind the rim's deepest notch
        along = (blocks.vertices[ids] - cap.center) @ (cap.normal / np.linalg.norm(cap.normal))
        assert np.ptp(along) < 1e-6 and -cap_recess(cap) - 1e-6 < along[0] <= 0.0


def test_planar_rims_keep_their_end_sections_on_the_cap():
    sdf, caps, sk = ragged_tube(0, depth=0.0)
    assert max(cap_recess(c) for c in caps) < 1e-6
    blocks = build_blocks(sk, sdf.distance, caps, BlockOptions(), intersect_lines=sdf.intersect_lines)
    for cap in caps:
        b, f = np.nonzero(blocks.face_boundary == cap.id)
        ids = np.unique(blocks.hexes[b[:, None], HEX_FACES[f]])
        assert np.abs((blocks.vertices[ids] - cap.center) @ cap.normal).max() < 1e-9
