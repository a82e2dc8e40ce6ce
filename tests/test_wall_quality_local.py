"""The block builder's wall-fold checks re-project only the wall faces a fix moved (issue 17/18).

On a tree of thousands of sections each thickening round and the junction re-placements
used to project every wall face of the tree again (on a whole-brain arterial tree: 7
whole-tree projections, a quarter of the builder); a face's projected quality depends on its eight corners alone,
so faces whose corners stayed put keep their value.
"""

from __future__ import annotations

import numpy as np

from vmesh.geometry.block_builder import BlockOptions, build_blocks, projected_wall_quality
from vmesh.geometry.blocks.builder import _Builder
from vmesh.geometry.blocks.checks import _OPPOSITE

from test_blocks import star_distance, star_skeleton

DIRS = [[1, 0, 0], [-0.5, 0.8, 0.1], [-0.5, -0.8, -0.1]]


def _radial(radius=1.0, length=8.0):
    """Closest points on the star's capsules (the wall of ``star_distance``), counted."""
    d = np.asarray(DIRS, float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    seen = []

    def project(p):
        p = np.asarray(p, float).reshape(-1, 3)
        seen.append(len(p))
        t = np.clip(p @ d.T, 0.0, length + 2 * radius)  # (n, 3) along each branch
        foot = t[:, :, None] * d[None]
        off = p[:, None] - foot
        dist = np.linalg.norm(off, axis=2)
        k = np.argmin(np.abs(dist - radius) + 10 * (t <= 0), axis=1)  # the nearest tube's wall
        o, f = off[np.arange(len(p)), k], foot[np.arange(len(p)), k]
        return f + o * (radius / np.maximum(np.linalg.norm(o, axis=1, keepdims=True), 1e-300))

    return project, seen


def _blocks():
    sk = star_skeleton(DIRS)
    project, _ = _radial()
    return build_blocks(sk, star_distance(DIRS), None, BlockOptions(), project=project)


def test_moved_faces_only_are_projected_again_with_the_whole_trees_result():
    blocks = _blocks()
    project, seen = _radial()
    last = {}
    first = projected_wall_quality(blocks, project, last=last)
    n_faces = len(last["faces"])
    assert n_faces > 50 and sum(seen) == n_faces * 25  # a 5 x 5 grid per wall face, once
    assert np.array_equal(first, projected_wall_quality(blocks, project))
    # nothing moved: nothing is projected again
    seen.clear()
    assert np.array_equal(projected_wall_quality(blocks, project, last=last), first)
    assert sum(seen) == 0
    # pull the inner corners of a few boundary-layer blocks towards the wall: those faces
    # (and the faces sharing the moved vertices) are projected again, and the result is the
    # whole structure's
    b, f = last["faces"][:3].T
    moved = np.unique(blocks.hexes[b[:, None], _OPPOSITE[f]])
    blocks.vertices[moved] += 0.9 * (project(blocks.vertices[moved]) - blocks.vertices[moved])
    seen.clear()
    local = projected_wall_quality(blocks, project, last=last)
    redone = sum(seen) // 25
    assert 3 <= redone < n_faces // 4
    seen.clear()
    whole = projected_wall_quality(blocks, project)
    assert np.array_equal(local, whole)
    assert local[b].min() < first[b].min()  # the thinner layer folds more


def test_builder_keeps_its_wall_faces_across_steps():
    """The builder's own cache: after a build, checking the same blocks again projects nothing."""
    sk = star_skeleton(DIRS)
    project, seen = _radial()
    builder = _Builder(sk, star_distance(DIRS), None, BlockOptions(), None, None, project)
    blocks = builder.run()
    assert builder.built.wall_faces  # report_wall_folds filled it
    seen.clear()
    q = builder._wall_quality(blocks)
    assert sum(seen) == 0
    assert np.array_equal(q, projected_wall_quality(blocks, project))


def test_half_plane_blocks_are_those_with_a_vertex_of_its_half_section():
    """The re-rotation's blocks per half-plane, from one vertex map, are those of the
    definition (a vertex of the half-section off the spine), half-plane by half-plane."""
    sk = star_skeleton(DIRS)
    project, _ = _radial()
    builder = _Builder(sk, star_distance(DIRS), None, BlockOptions(), None, None, project)
    blocks = builder.run()
    seps = [(c, sp) for c, j in builder.topo.junctions.items() for sp in range(len(j.neighbors))]
    assert len(seps) == 3
    got = builder._half_plane_blocks(blocks, seps)
    for (c, sp), mine in zip(seps, got):
        j = builder.topo.junctions[c]
        own = j.half_ids[sp][j.spine_ids < 0]
        want = np.flatnonzero(np.isin(blocks.hexes, own[own >= 0]).any(axis=1))
        assert len(want) and np.array_equal(mine, want)
