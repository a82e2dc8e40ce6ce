"""Checks of the committed synthetic vessel cases in ``data_synthetic/``.

The tests read the committed files (nothing is regenerated except one small
case for the determinism check) and verify the surface topology, the skeleton
format and the case-specific ground truth the mesher tests rely on.
"""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from data_synthetic.generate import CASES, DATA_DIR, case_paths, make_case  # noqa: E402

meshio = pytest.importorskip("meshio")

# Per case: Euler characteristic, independent cycles, {degree: count} of
# junction nodes (degree >= 3) and number of end nodes (degree 1).
EXPECTED = {
    "straight_tube": dict(euler=2, cycles=0, junctions={}, ends=2),
    "curved_tube": dict(euler=2, cycles=0, junctions={}, ends=2),
    "y_bifurcation": dict(euler=2, cycles=0, junctions={3: 1}, ends=3),
    "trifurcation": dict(euler=2, cycles=0, junctions={4: 1}, ends=4),
    "five_furcation": dict(euler=2, cycles=0, junctions={5: 1}, ends=5),
    "two_junctions": dict(euler=2, cycles=0, junctions={3: 2}, ends=4),
    "uneven_bifurcation": dict(euler=2, cycles=0, junctions={3: 1}, ends=3),
    "aneurysm": dict(euler=2, cycles=0, junctions={3: 1}, ends=3),
    "coarctation": dict(euler=2, cycles=0, junctions={3: 3}, ends=5),
    "cerebral_tree": dict(euler=2, cycles=0, junctions=None, ends=None),
    "ring": dict(euler=0, cycles=1, junctions={3: 6}, ends=6),
}


def test_expectations_cover_all_cases():
    assert sorted(EXPECTED) == sorted(CASES)


# ----------------------------------------------------------------------------
# Loading and geometry helpers
# ----------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def load(name):
    """(vertices, faces, skeleton) of a committed case."""
    base = DATA_DIR / name
    mesh = meshio.read(base / "surface.ply")
    tri = [c.data for c in mesh.cells if c.type == "triangle"]
    assert len(tri) == len(mesh.cells) == 1, "surface must consist of triangles only"
    V = np.asarray(mesh.points, dtype=float)
    F = np.asarray(tri[0], dtype=np.int64)
    skel = json.loads((base / "skeleton.json").read_text())
    return V, F, skel


def graph(skel):
    """Node coordinates, radii, degrees and neighbour lists of a skeleton."""
    X = np.array([n["xyz"] for n in skel["nodes"]], dtype=float)
    r = np.array([n["radius"] for n in skel["nodes"]], dtype=float)
    nbr = [[] for _ in skel["nodes"]]
    for i, j in skel["edges"]:
        nbr[i].append(j)
        nbr[j].append(i)
    deg = np.array([len(x) for x in nbr])
    return X, r, deg, nbr


def tags(skel, tag):
    return [n["id"] for n in skel["nodes"] if tag in n.get("tags", [])]


def unit(v):
    return v / np.linalg.norm(v)


def winding_numbers(V, F, Q):
    """Generalised winding numbers (igl if available, exact solid angles otherwise)."""
    try:
        import igl
        return igl.fast_winding_number(V, F, np.asarray(Q, dtype=float))
    except ImportError:                             # pragma: no cover
        out = np.zeros(len(Q))
        for k, q in enumerate(Q):
            a, b, c = (V[F[:, i]] - q for i in range(3))
            la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
            num = np.einsum("ij,ij->i", a, np.cross(b, c))
            den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
                   + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb)
            out[k] = np.arctan2(num, den).sum() / (2 * np.pi)
        return out


def vertex_fans(nv, F):
    """Number of face fans around vertices (== used vertices iff vertex-manifold)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    src, dst = F.ravel(), F[:, [1, 2, 0]].ravel()
    key = src * nv + dst
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], dst * nv + src)]
    h = np.arange(len(src))
    nxt = 3 * (h // 3) + (h % 3 + 1) % 3
    tnxt = 3 * (twin // 3) + (twin % 3 + 1) % 3
    A = coo_matrix((np.ones(2 * len(h)), (np.r_[h, nxt], np.r_[tnxt, twin])), shape=(len(h), len(h)))
    return connected_components(A, directed=False)[0]


# ----------------------------------------------------------------------------
# Surface
# ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", CASES)
def test_files_present_and_small(name):
    surf, sk = DATA_DIR / name / "surface.ply", DATA_DIR / name / "skeleton.json"
    assert surf.exists() and sk.exists()
    limit = 2_600_000 if name == "cerebral_tree" else 620_000
    assert surf.stat().st_size + sk.stat().st_size <= limit
    assert surf.read_bytes()[:4] == b"ply\n"
    assert b"binary_little_endian" in surf.read_bytes()[:200]


@pytest.mark.parametrize("name", CASES)
def test_surface_closed_manifold_oriented(name):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V, F, _ = load(name)
    assert F.min() >= 0 and F.max() < len(V)
    assert np.all((F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0]))
    # Closed and edge-manifold: every undirected edge in exactly two faces.
    und = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, counts = np.unique(und, axis=0, return_counts=True)
    assert np.all(counts == 2), f"{np.sum(counts == 1)} boundary, {np.sum(counts > 2)} non-manifold edges"
    # Consistently oriented: each directed edge once (its twin in the other face).
    directed = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len(np.unique(directed, axis=0)) == len(directed)
    # Vertex-manifold and one connected component.
    used = np.unique(F)
    assert len(used) == len(V), "unreferenced vertices"
    assert vertex_fans(len(V), F) == len(V)
    e = F[:, [0, 1, 1, 2]].reshape(-1, 2)
    ncomp = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])),
                                            shape=(len(V), len(V))), directed=False)[0]
    assert ncomp == 1
    # Outward orientation: positive signed volume.
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6 > 0
    # Genus: Euler characteristic 2 (sphere-like) or 0 (ring).
    assert len(V) - len(edges) + len(F) == EXPECTED[name]["euler"]


@pytest.mark.parametrize("name", CASES)
def test_triangle_count(name):
    _, F, _ = load(name)
    if name == "cerebral_tree":
        assert 80_000 <= len(F) <= 120_000
    else:
        assert 5_000 <= len(F) <= 20_000


# ----------------------------------------------------------------------------
# Skeleton
# ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", CASES)
def test_skeleton_format(name):
    _, _, skel = load(name)
    assert skel["name"] == name and skel["units"] == "mm"
    assert set(skel) == {"name", "units", "nodes", "edges"}
    for k, n in enumerate(skel["nodes"]):
        assert n["id"] == k
        assert len(n["xyz"]) == 3 and all(np.isfinite(n["xyz"]))
        assert n["radius"] > 0
        assert isinstance(n.get("tags", []), list)
        assert all(isinstance(t, str) for t in n.get("tags", []))
    E = np.array(skel["edges"])
    assert E.ndim == 2 and E.shape[1] == 2
    assert E.min() >= 0 and E.max() < len(skel["nodes"])
    assert np.all(E[:, 0] != E[:, 1])
    assert len(np.unique(np.sort(E, axis=1), axis=0)) == len(E)


@pytest.mark.parametrize("name", CASES)
def test_skeleton_graph(name):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, _, skel = load(name)
    n, E = len(skel["nodes"]), np.array(skel["edges"])
    ncomp = connected_components(coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)),
                                 directed=False)[0]
    assert ncomp == 1
    assert len(E) - n + 1 == EXPECTED[name]["cycles"]
    _, _, deg, _ = graph(skel)
    exp = EXPECTED[name]
    if exp["junctions"] is not None:
        got = {int(d): int(np.sum(deg == d)) for d in np.unique(deg[deg >= 3])}
        assert got == exp["junctions"]
        assert np.sum(deg == 1) == exp["ends"]


@pytest.mark.parametrize("name", CASES)
def test_node_spacing(name):
    """Coarse skeleton: edges about 1-1.5 local radii long."""
    _, _, skel = load(name)
    X, r, _, _ = graph(skel)
    E = np.array(skel["edges"])
    L = np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1)
    q = L / np.minimum(r[E[:, 0]], r[E[:, 1]])
    assert 1.0 <= np.median(q) <= 1.5
    assert q.min() > 0.4 and q.max() < 1.8


@pytest.mark.parametrize("name", CASES)
def test_nodes_inside_surface(name):
    """Every node is inside; end nodes sit on their cap (inside once nudged in)."""
    V, F, skel = load(name)
    X, r, deg, nbr = graph(skel)
    Q = X.copy()
    ends = [i for i, n in enumerate(skel["nodes"]) if {"inlet", "outlet"} & set(n["tags"])]
    for i in ends:
        Q[i] += 0.05 * r[i] * unit(X[nbr[i][0]] - X[i])
    w = winding_numbers(V, F, Q)
    assert np.all(w > 0.9), f"nodes outside: {np.nonzero(w <= 0.9)[0].tolist()}"


@pytest.mark.parametrize("name", CASES)
def test_flat_caps(name):
    """Each capped end node is the centre of a planar disc square to its end segment."""
    V, F, skel = load(name)
    X, r, deg, nbr = graph(skel)
    ends = [i for i, n in enumerate(skel["nodes"]) if {"inlet", "outlet"} & set(n["tags"])]
    assert ends and all(deg[i] == 1 for i in ends)
    for i in ends:
        n = unit(X[i] - X[nbr[i][0]])
        d = (V - X[i]) @ n
        radial = np.linalg.norm((V - X[i]) - d[:, None] * n, axis=1)
        on = (np.abs(d) < 1e-4 * r[i] + 5e-5) & (radial < 1.2 * r[i])
        assert on.sum() >= 6, f"node {i}: no cap"
        # The disc reaches the vessel wall (sharp rim at the vessel radius).
        assert abs(radial[on].max() / r[i] - 1) < 0.06, f"node {i}: rim {radial[on].max() / r[i]:.3f} r"
        # Nothing of the vessel sticks out beyond the cap plane near the cap.
        near = (radial < 1.2 * r[i]) & (np.linalg.norm(V - X[i], axis=1) < 3 * r[i])
        assert d[near].max() < 1e-4 * r[i] + 5e-5
        # Cap faces point outwards along the end segment.
        cap = on[F].all(axis=1)
        a, b, c = V[F[cap, 0]], V[F[cap, 1]], V[F[cap, 2]]
        fn = np.cross(b - a, c - a)
        assert cap.sum() >= 4 and np.all(fn @ n > 0)


# ----------------------------------------------------------------------------
# Case-specific ground truth
# ----------------------------------------------------------------------------

def test_inlets_and_outlets():
    for name in CASES:
        _, _, skel = load(name)
        _, _, deg, _ = graph(skel)
        inlets, outlets = tags(skel, "inlet"), tags(skel, "outlet")
        expected_inlets = 3 if name == "ring" else 1
        assert len(inlets) == expected_inlets, name
        ends = set(np.nonzero(deg == 1)[0].tolist())
        capped = set(inlets) | set(outlets)
        # Every end is capped except the aneurysm dome.
        assert ends - capped == (set(tags(skel, "aneurysm")) & ends), name


def test_five_furcation_is_planar():
    _, _, skel = load("five_furcation")
    X, _, deg, nbr = graph(skel)
    (j,) = np.nonzero(deg == 5)[0]
    dirs = np.array([unit(X[k] - X[j]) for k in nbr[j]])
    normal = np.linalg.svd(dirs)[2][-1]              # best plane through the junction
    out_of_plane = np.degrees(np.arcsin(np.abs(dirs @ normal)))
    assert out_of_plane.max() < 10


def test_two_junctions_are_close():
    _, _, skel = load("two_junctions")
    X, r, deg, _ = graph(skel)
    a, b = np.nonzero(deg == 3)[0]
    dist = np.linalg.norm(X[a] - X[b])
    assert dist <= 2 * max(r[a], r[b])
    assert dist >= 1.0 * min(r[a], r[b])


def test_uneven_bifurcation_radii():
    _, _, skel = load("uneven_bifurcation")
    X, r, deg, nbr = graph(skel)
    (j,) = np.nonzero(deg == 3)[0]
    rn = np.sort(r[nbr[j]])
    assert rn[-1] / rn[0] > 2.5


def test_aneurysm_tags():
    V, F, skel = load("aneurysm")
    X, r, deg, nbr = graph(skel)
    sac, neck, vessel = tags(skel, "aneurysm"), tags(skel, "neck"), tags(skel, "vessel")
    assert len(sac) >= 1 and len(neck) == 1 and len(vessel) >= 10
    assert not set(sac) & set(vessel) and not set(neck) & set(vessel)
    (j,) = np.nonzero(deg == 3)[0]
    assert j in vessel and neck[0] in nbr[j]       # junction -> neck -> sac
    assert all(r[s] > 1.4 * r[j] for s in sac)       # sac wider than the vessel
    # The sac is closed: its end is rounded, not a cap.
    assert not ({"inlet", "outlet"} & set(skel["nodes"][sac[-1]]["tags"]))


def test_coarctation_narrowing():
    _, _, skel = load("coarctation")
    X, r, deg, nbr = graph(skel)
    co = tags(skel, "coarctation")
    assert len(co) >= 2
    assert all(deg[i] == 2 for i in co)
    assert 0.45 < r[co].min() / 10.0 < 0.55          # 50 % of the nominal 10 mm radius
    assert r.max() >= 10
    junction_r = sorted(min(r[k] for k in nbr[j]) for j in np.nonzero(deg == 3)[0])
    assert all(3 <= x <= 5.5 for x in junction_r)    # supra-aortic branches r 3-5


def test_cerebral_tree():
    _, _, skel = load("cerebral_tree")
    X, r, deg, nbr = graph(skel)
    assert 500 <= len(X) <= 600
    assert deg.max() == 3
    assert 1.8 <= r.max() <= 2.2 and 0.45 <= r.min() <= 0.55
    # Radii never grow downstream (breadth-first from the inlet).
    (root,) = tags(skel, "inlet")
    parent = {root: -1}
    order = [root]
    for i in order:
        for k in nbr[i]:
            if k not in parent:
                parent[k] = i
                order.append(k)
    for i in order[1:]:
        assert r[i] <= r[parent[i]] + 1e-6
    # Murray-like junctions: rp^3 close to the sum of children's r^3.
    for j in np.nonzero(deg == 3)[0]:
        kids = [k for k in nbr[j] if parent.get(k) == j]
        ratio = sum(r[k] ** 3 for k in kids) / r[j] ** 3
        assert 0.7 < ratio < 1.45


def test_ring():
    _, _, skel = load("ring")
    assert len(tags(skel, "inlet")) >= 2 and len(tags(skel, "outlet")) >= 2


# ----------------------------------------------------------------------------
# Generator
# ----------------------------------------------------------------------------

def test_case_paths_returns_committed_files():
    for name in CASES:
        surf, sk = case_paths(name)
        assert surf == DATA_DIR / name / "surface.ply"
        assert sk == DATA_DIR / name / "skeleton.json"
    with pytest.raises(ValueError):
        case_paths("no_such_case")


def test_regeneration_is_deterministic():
    V, F, skel = make_case("y_bifurcation")
    V0, F0, skel0 = load("y_bifurcation")
    assert skel == skel0
    np.testing.assert_array_equal(F, F0)
    np.testing.assert_array_equal(V.astype(np.float32), V0.astype(np.float32))


def test_radius_scale_keeps_centrelines():
    V, F, skel = make_case("straight_tube", radius_scale=1.5)
    _, _, skel0 = load("straight_tube")
    X0, r0, _, _ = graph(skel0)
    X, r, _, _ = graph(skel)
    np.testing.assert_allclose(X, X0)
    np.testing.assert_allclose(r, 1.5 * r0, rtol=1e-5)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6
    assert vol == pytest.approx(np.pi * (4.5 ** 2) * 40, rel=0.03)
