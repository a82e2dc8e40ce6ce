"""Cross-sections added where the wall dips between two sections (issue 17/18, session 17,
branch h17/dents; :mod:`vmesh.geometry.blocks.dents`).

A tube of radius 1 with skeleton segments 3 radii long and a ball pressed 0.6 radii into
its wall halfway between two nodes: the boundary-layer blocks of that segment run straight
over the dent, the builder flags them (their wall faces fold once projected onto the wall)
and the raw fill folds there, as in seed 0 g0007 extracted and seed 1 g0016 extracted
(docs/optimiser.md h16/dents: the dips lie along the skeleton). With a section added halfway
along that segment the layer follows the dent and the fill is valid."""

import numpy as np

from junction_cases import JunctionCase
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.blocks.checks import projected_wall_quality
from vmesh.geometry.blocks.dents import halve_segments
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks
from vmesh.skeleton import Skeleton

#: the default chain's element counts and curved sections (mesh_transfinite defaults)
DEFAULT = Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02, curved_sections=True)


class _Dented(JunctionCase):
    """Capsules with a ball of radius ``ball`` at ``centre`` taken out of them."""

    centre = np.zeros(3)
    ball = 1.0

    def distance(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, float).reshape(-1, 3)
        return np.minimum(super().distance(p), np.linalg.norm(p - self.centre, axis=1) - self.ball)


def dented_tube(segment: float, depth: float, ball: float, n: int = 4):
    """A straight tube of radius 1 on ``n`` skeleton segments ``segment`` long, with a ball
    of radius ``ball`` pressed ``depth`` into its wall halfway along segment ``n // 2 - 1``."""
    length = segment * n
    P = np.c_[np.linspace(0.0, length, n + 1), np.zeros(n + 1), np.zeros(n + 1)]
    sk = Skeleton(P, np.ones(n + 1), np.c_[np.arange(n), np.arange(1, n + 1)])
    case = _Dented("dented", np.array([[-1.0, 0, 0]]), np.array([[length + 1.0, 0, 0]]), np.ones(1), sk)
    case.centre = np.array([segment * (n // 2 - 0.5), 1.0 + ball - depth, 0.0])
    case.ball = ball
    return case, sk


def _built(case, sk, rounds):
    blocks = build_blocks(sk, case.distance, None, BlockOptions(dent_sections=rounds), project=case.project)
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    return blocks, projected_wall_quality(blocks, case.project), scaled_jacobian(sm.points, sm.cells, 1)


def test_a_section_over_the_dent_unfolds_the_layer():
    case, sk = dented_tube(3.0, 0.6, 1.5)
    before, q0, sj0 = _built(case, sk, 0)
    assert np.sum(q0 <= 0) > 0 and np.sum(sj0 <= 0) > 0  # flagged, and the raw fill folds
    after, q1, sj1 = _built(case, sk, 2)
    assert after.info["dent_sections"] == 1  # the dented segment alone
    added = after.info["skeleton"].points[sk.n_nodes:]
    assert np.allclose(added, [[4.5, 0.0, 0.0]])
    assert np.all(q1 > 0)
    assert sj1.min() > 0.25, f"{int((sj1 <= 0).sum())} inverted, least scaled Jacobian {sj1.min():.3f}"


def test_a_dent_the_layer_follows_is_left_as_built():
    """A smaller ball as deep: no block is flagged, so nothing is added and the structure
    is the one built without the step."""
    case, sk = dented_tube(3.0, 0.6, 0.5)
    before, q0, _ = _built(case, sk, 0)
    after, q1, _ = _built(case, sk, 2)
    assert np.all(q0 > 0)
    assert "dent_sections" not in after.info
    assert after.info["skeleton"].n_nodes == sk.n_nodes
    assert np.array_equal(after.vertices, before.vertices)


def test_halve_segments_keeps_ids_and_shared_tags():
    sk = Skeleton(np.array([[0.0, 0, 0], [2, 0, 0], [4, 0, 0]]), np.array([1.0, 2.0, 1.0]), np.array([[0, 1], [1, 2]]),
                  node_tags=[("inlet", "a"), ("a",), ("a", "outlet")], edge_tags=[("x",), ("y",)])
    out = halve_segments(sk, np.array([1]))
    assert out.edges.tolist() == [[0, 1], [1, 3], [3, 2]]
    assert np.allclose(out.points[3], [3, 0, 0]) and out.radii[3] == 1.5
    assert out.node_tags[3] == ("a",) and out.edge_tags == [("x",), ("y",), ("y",)]


def _rebuilds(case):
    from vmesh.geometry.blocks.builder import _build_blocks, _Rebuilds
    from vmesh.geometry.rays import RayCache

    calls = []

    def build(sk, heard, work):
        calls.append(sk.n_edges)
        return _build_blocks(sk, case.distance, None, BlockOptions(), None, heard.append, None, case.project, None, work)

    return _Rebuilds(build, 0, RayCache()), calls


def test_rebuilds_remember_a_skeleton_and_relabel_a_renumbered_one():
    """The dent step's rebuilds (builder._Rebuilds): the same skeleton is built once (each
    caller gets its own copy); the same skeleton with the new nodes numbered otherwise (round
    2 halving on top of round 1's kept halving) gets that build relabelled, the same blocks
    with the same segments by position as its own build, and ``exact`` builds it."""
    case, sk = dented_tube(3.0, 0.6, 1.5)
    rebuild, calls = _rebuilds(case)
    first = halve_segments(sk, np.array([0, 2]))
    a, _ = rebuild(first)
    a.info["fixes"].append("changed by its caller")
    b, _ = rebuild(halve_segments(sk, np.array([0, 2])))
    assert len(calls) == 1 and "changed by its caller" not in b.info["fixes"]
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.hexes, b.hexes)
    renumbered = halve_segments(halve_segments(sk, np.array([2])), np.array([0]))
    relabelled, _ = rebuild(renumbered)
    assert len(calls) == 1 and relabelled.info["relabelled"] and relabelled.info["skeleton"] is renumbered
    own, _ = rebuild.exact(renumbered)
    assert len(calls) == 2 and "relabelled" not in own.info

    def by_corners(blocks):  # blocks in corner order, with their segments' end points
        corners = blocks.vertices[blocks.hexes].reshape(blocks.n_blocks, -1)
        order = np.lexsort(corners.T[::-1])
        ends = np.sort(renumbered.points[renumbered.edges[blocks.block_segment[order]]].reshape(len(order), -1), axis=1)
        return corners[order], ends, renumbered.points[blocks.block_node[order]]

    for got, want in zip(by_corners(relabelled), by_corners(own)):
        assert np.array_equal(got, want)


def test_same_blocks_ignores_block_order_not_corners():
    """The dent step's check that the build it keeps is the copy it judged: the same corners
    in another block order are the same blocks; one moved corner is not."""
    from types import SimpleNamespace as Blocks  # the corners are all it reads

    from vmesh.geometry.blocks.dents import _same_blocks

    v = np.random.default_rng(0).random((12, 3))
    hexes = np.array([[0, 1, 2, 3, 4, 5, 6, 7], [4, 5, 6, 7, 8, 9, 10, 11]])
    a = Blocks(vertices=v, hexes=hexes)
    assert _same_blocks(a, Blocks(vertices=v, hexes=hexes[::-1]))
    moved = v.copy()
    moved[9] += 1e-9
    assert not _same_blocks(a, Blocks(vertices=moved, hexes=hexes))
