"""Cross-sections that cross their neighbour in a bend: the bend's node dropped after every
other try failed (issue 17, session 24, branch h24/realbuild; :mod:`vmesh.geometry.blocks.crossings`).

Real hepatic_artery extracted: the trunk flattens to a lumen about 21 x 11 wide, the
extracted skeleton wanders over its medial sheet with node radii of 2.7-2.9 (the thin
side), turning 29-37 degrees at nodes 3.3-5.6 apart. The sections' rays reach the wide side,
8-13 from the node, so two sections tilted by a bend cross each other inside the lumen; the
fix loop's straightening leaves them crossing and the build failed ("3 block(s) stay
invalid ... skeleton node 887"). The generated vessel here has the same configuration: a
tube of radius 10 whose skeleton (radius 3 at every node) turns 29-36 degrees at nodes
3.3-5.6 apart, the turns of hepatic's nodes 886-890. (Session 25 re-read hepatic: its trunk
is round and the short rays end on a thin pillar through the lumen, docs/junctions.md
h25/realbuild; the vessel here stays the configuration of a skeleton winding in a wide lumen,
which ``centre_sections`` also builds: tests/test_centred_sections.py.)"""

import numpy as np
import pytest

from junction_cases import JunctionCase
from test_dent_sections import DEFAULT
from vmesh.errors import MeshingError
from vmesh.geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
from vmesh.geometry.blocks.crossings import crossing_bends, without_bends
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import mesh_blocks
from vmesh.skeleton import Skeleton

LUMEN = 10.0  # the tube's radius: the reach of the sections' rays
NODE_RADIUS = 3.0  # the skeleton's radii, the lumen's thin side in hepatic (2.7-2.9 against rays of 8-13)


def winding_skeleton(turns=(36.0, 4.0, -29.0, -32.0, 19.0), gaps=(3.4, 3.3, 5.6, 3.9, 4.0), straight: int = 4, step: float = 3.3):
    """A tube of radius ``LUMEN`` along x and a skeleton inside it (radius ``NODE_RADIUS``)
    that runs ``straight`` segments ``step`` long, turns ``turns`` degrees in the xy plane at
    nodes ``gaps`` apart, and runs ``straight`` segments on."""
    heading, P = 0.0, [np.zeros(3)]
    for gap, turn in [(step, 0.0)] * straight + list(zip(gaps, turns)) + [(step, 0.0)] * straight:
        heading += np.radians(turn)
        P.append(P[-1] + gap * np.array([np.cos(heading), np.sin(heading), 0.0]))
    P = np.asarray(P)
    P[:, 1] -= 0.5 * (P[:, 1].max() + P[:, 1].min())
    n = len(P)
    sk = Skeleton(P, np.full(n, NODE_RADIUS), np.c_[np.arange(n - 1), np.arange(1, n)])
    case = JunctionCase("winding", np.array([[P[0, 0] - LUMEN, 0, 0]]), np.array([[P[-1, 0] + LUMEN, 0, 0]]), np.array([LUMEN]), sk)
    return case, sk


def test_sections_crossing_in_a_bend_fail_without_the_drop():
    """As on main: ``bend_drops`` is opt-in (0 by default)."""
    case, sk = winding_skeleton()
    assert case.distance(sk.points).min() > 2.0  # every node well inside
    with pytest.raises(MeshingError, match="stay invalid"):
        build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0), project=case.project)


def test_the_bend_node_dropped_gives_valid_blocks_and_elements():
    case, sk = winding_skeleton()
    blocks = build_blocks(sk, case.distance, None, BlockOptions(bend_drops=1, dent_sections=0), project=case.project)
    checks = block_structure_checks(blocks)
    assert checks["invalid_blocks"] == checks["face_use_errors"] == 0
    assert blocks.corner_jacobians().min() > 0
    dropped = [f for f in blocks.info["fixes"] if f.startswith("dropped the cross-section")]
    assert len(dropped) == 1
    built_on = blocks.info["skeleton"]
    assert 0 < sk.n_nodes - built_on.n_nodes <= 3  # a node a failing bend, no more
    assert built_on.n_components == 1 and np.isin(built_on.points, sk.points).all(axis=1).all()  # the others kept
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    sj = scaled_jacobian(sm.points, sm.cells, 1)
    assert sj.min() > 0
    # the mesh spans the skeleton's whole length
    assert sm.points[:, 0].min() <= sk.points[0, 0] + 1e-6 and sm.points[:, 0].max() >= sk.points[-1, 0] - 1e-6


def test_crossing_bends_picks_the_sharper_turn_of_a_stuck_segment():
    """Only segments between two regular sections that the fix loop has straightened fully
    count; of their two nodes the one where the skeleton turns more is dropped."""
    case, sk = winding_skeleton()  # fails without the drop: test_sections_crossing_in_a_bend_fail_without_the_drop
    from vmesh.geometry.blocks.builder import _Builder
    from vmesh.geometry.blocks.checks import _Failure
    from vmesh.geometry.blocks.work import WorkBudget

    b = _Builder(sk, case.distance, None, BlockOptions(bend_drops=1, dent_sections=0), None, None, work=WorkBudget(160))
    with pytest.raises(_Failure) as got:
        b.make_valid()
    bends = got.value.bends
    assert bends and all(sk.degrees[n] == 2 for n in bends)
    turn = np.degrees([np.arccos(np.clip(np.dot(*[(sk.points[n + 1] - sk.points[n]) / np.linalg.norm(sk.points[n + 1] - sk.points[n]),
                                                 (sk.points[n] - sk.points[n - 1]) / np.linalg.norm(sk.points[n] - sk.points[n - 1])][::-1]), -1, 1))
                       for n in bends])
    assert (turn > 20).all()  # bends, not the straight nodes beside them
    # of its failing segment's two nodes, each picked one turns more than the other
    turns = {n: _turn_deg(sk.points, n) for n in range(1, sk.n_nodes - 1)}
    assert all(any(turns[n] >= turns.get(m, 0.0) for m in (n - 1, n + 1)) for n in bends)
    assert without_bends(sk, bends).n_nodes == sk.n_nodes - len(bends)
    assert crossing_bends(b, np.zeros(0, np.int64)) == []


def _turn_deg(points, n):
    """The skeleton's turn (degrees) at node ``n`` of a chain."""
    a, b = points[n] - points[n - 1], points[n + 1] - points[n]
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _stuck_builder(points, failing_segments):
    """A stand-in for a :class:`~vmesh.geometry.blocks.builder._Builder` after its fix loop:
    one open branch along ``points`` with every section straightened as far as it goes,
    one invalid block on each of ``failing_segments``."""
    from types import SimpleNamespace

    from vmesh.geometry.blocks.options import OPEN

    K = len(points)
    branch = SimpleNamespace(nodes=np.arange(K), kinds=(OPEN, OPEN), straighten=np.ones(K))
    where = np.array([[0, k] for k in failing_segments], np.int64)
    return SimpleNamespace(topo=SimpleNamespace(branches=[branch], pos=np.asarray(points, float)), built=SimpleNamespace(block_where=where))


def _zigzag(turns_deg):
    """A planar chain of unit segments turning ``turns_deg`` at its interior nodes."""
    heading, P = 0.0, [np.zeros(3)]
    for t in (0.0,) + tuple(turns_deg):
        heading += np.radians(t)
        P.append(P[-1] + np.array([np.cos(heading), np.sin(heading), 0.0]))
    return np.asarray(P)


def test_crossing_bends_drops_the_sharper_node_of_each_failing_segment():
    P = _zigzag((10.0, 40.0, 5.0, 30.0, 12.0))  # 7 nodes, interior turns at nodes 1..5
    b = _stuck_builder(P, [1, 3])  # segment 1-2: node 2 (40) sharper; segment 3-4: node 4 (30)
    assert crossing_bends(b, np.arange(2)) == [2, 4]


def test_crossing_bends_leaves_a_branch_one_regular_section():
    """A 4-node branch failing on both its end segments would lose both interior nodes (no
    regular section left): it gives only the sharper one."""
    P = _zigzag((25.0, 35.0))  # nodes 1 (25) and 2 (35) interior
    b = _stuck_builder(P, [0, 2])  # segment 0-1 picks node 1, segment 2-3 picks node 2
    assert crossing_bends(b, np.arange(2)) == [2]
    five = _stuck_builder(_zigzag((25.0, 5.0, 35.0)), [0, 3])  # 5 nodes: two may go
    assert crossing_bends(five, np.arange(2)) == [1, 3]


def test_bend_drop_rounds_share_one_extra_work_budget(monkeypatch):
    """Every bend-drop round draws on one extra ``work_budget`` (not one each): with
    ``bend_drops = 3`` and rounds that spend 100 assemblies each against a budget of 160, the
    second round runs (60 left) and the third does not."""
    from types import SimpleNamespace

    import vmesh.geometry.blocks.builder as builder
    from vmesh.geometry.blocks.work import WorkBudget

    _, sk = winding_skeleton()
    first = SimpleNamespace(bends=[5], skeleton=sk, hint="")
    rounds = []

    def failing_build(skeleton, distance, caps, options, path, *hooks_and_work):
        work = hooks_and_work[-1]
        rounds.append(work)
        work.used += 100
        if builder._without_bends(first, distance, caps, options, hooks_and_work[:-1], work) is None:
            raise MeshingError("still invalid")

    monkeypatch.setattr(builder, "_build_blocks", failing_build)
    spent = WorkBudget(160)
    spent.used = 160
    options = BlockOptions(bend_drops=3, work_budget=160)
    assert builder._without_bends(first, None, None, options, (None, None, None, None), spent) is None
    assert len(rounds) == 2 and rounds[0] is rounds[1] is not spent
    assert rounds[0].limit == 160 and rounds[0].rays is spent.rays
    assert "did not help" in first.hint


def test_a_build_with_nothing_tried_fails_with_a_meshing_error():
    """A work budget spent before the first assembly (a rebuild handed a spent budget) or no
    tries allowed (the last tries still run) ends in a MeshingError that says so, not an
    AttributeError on the missing first failure (review of h24/mends)."""
    from vmesh.geometry.blocks.builder import _build_blocks
    from vmesh.geometry.blocks.work import WorkBudget

    case, sk = winding_skeleton()
    spent = WorkBudget(5)
    spent.used = 5
    with pytest.raises(MeshingError, match="no try of the skeleton was made.*work_budget = 5"):
        _build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0), work=spent)
    with pytest.raises(MeshingError, match="max_retopology_tries = 0"):
        _build_blocks(sk, case.distance, None, BlockOptions(dent_sections=0, max_retopology_tries=0))
