"""Procedural vessel trees with their true skeletons, for robustness benchmarks.

Every vessel is a random tree with realistic morphometry -- Murray's-law radii
(r0^3 = r1^3 + r2^3) with random asymmetry, branching angles near Murray's optimum plus
noise, tortuous axes with out-of-plane turns -- and, each with a controllable rate, the
hard features of real anatomy and of real segmentations:

==========================  =====================================================
feature                     what it is
==========================  =====================================================
``trifurcation``            a junction with 3 daughters (one out of plane)
``nfurcation``              a nearly planar junction with 4-5 daughters
``close_junctions``         two junctions less than 2 radii apart
``acute_angle``             two daughters less than 25 degrees apart
``large_ratio``             a side branch of 1/5 of its parent's radius
``kissing``                 a branch touching another vessel (surfaces meet)
``loop``                    an anastomosis closing a ring (circle of Willis)
``stenosis``                a 50-80 % narrowing
``aneurysm_apex``           a saccular aneurysm at a bifurcation apex
``aneurysm_side``           a saccular aneurysm on a side wall
``fusiform``                a fusiform dilatation (+50-100 %)
``radius_jump``             a sudden radius drop to 55-70 %
``stub``                    a side branch cut 1-2 of its radii beyond the wall
``hole``                    1-3 small holes in the wall
``noise``                   segmentation noise (smooth random bumps)
``staircase``               a voxel (staircase) surface, not smoothed
``ragged_ends``             open ends cut unevenly
``inward_normals``          every face reversed
``inconsistent_orientation``  a patch of reversed faces
``components``              2-3 separate trees in one file
==========================  =====================================================

plus the end style (``open`` ends, closed ``flat`` caps or ``round`` closed ends) and the
units (``mm``, ``cm`` or ``m``). Presets: ``clean`` (one piece, no touching vessels, no
defects), ``rough`` (stubs, touching vessels, holes, noise, ragged ends, orientation
defects, several pieces) and ``mixed`` (each vessel clean or rough at random).

Files of one vessel (``OUT/<name>/``)
-------------------------------------
``surface.vtp`` (or ``.stl`` / ``.ply``)
    the triangle surface, in the vessel's units.
``skeleton.swc``, ``skeleton_noradius.swc``
    the true skeleton as SWC (with radii, and with radius 0 = unknown); an SWC is a tree,
    so a loop's closing segment is left out of it (``skeleton.json`` has it).
``centerline.vtp``, ``centerline_noradius.vtp``
    VMTK-style centerlines: one polyline from the inlet to every other end (overlapping),
    point array ``MaximumInscribedSphereRadius`` (left out in the second file).
``skeleton.json``
    the skeleton in vmesh's node-edge JSON (loops included).
``manifest.json``
    seed, preset, units, end style and the features the vessel has (name -> count).

Usage
-----
::

    python -m data_synthetic.vessel_generator --n 20 --seed 1 --preset rough --out out/vessels

    from data_synthetic.vessel_generator import generate_vessel, write_vessel
    vessel = generate_vessel(seed=3, preset="clean")
    write_vessel(vessel, "out/v3")

The same seed and parameters give the same vessel (and files) on the same platform; vessel
``i`` of a corpus uses seed ``SeedSequence(seed).spawn(i + 1)[i]``, independent of ``n``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .vessels import surface as S
from .vessels import tree as T

#: Scale of one mm in each unit.
UNITS = {"mm": 1.0, "cm": 0.1, "m": 0.001}

#: Morphometry shared by the presets.
MORPHOLOGY = {"root_radius": 2.0, "generations": (3, 4), "min_radius": 0.55, "length_ratio": (6.0, 10.0),
              "taper": (0.88, 0.97), "tortuosity": 0.15, "asymmetry": 0.5, "angle_noise_deg": 6.0}

#: Feature rates: probability that a vessel has the feature.
JUNCTION_FEATURES = ("trifurcation", "nfurcation", "close_junctions", "acute_angle")
SHAPE_FEATURES = ("large_ratio", "loop", "stenosis", "aneurysm_apex", "aneurysm_side", "fusiform", "radius_jump")
DIRT_FEATURES = ("kissing", "stub", "hole", "noise", "staircase", "ragged_ends", "inward_normals",
                 "inconsistent_orientation", "components")
FEATURES = JUNCTION_FEATURES + SHAPE_FEATURES + DIRT_FEATURES

_CLEAN = {**{f: 0.12 for f in JUNCTION_FEATURES}, **{f: 0.1 for f in SHAPE_FEATURES}, **{f: 0.0 for f in DIRT_FEATURES}}
PRESETS = {
    "clean": {"rates": _CLEAN, "end_styles": {"open": 0.5, "flat": 0.3, "round": 0.2}, "units": {"mm": 1.0},
              "formats": {"vtp": 1.0}},
    "rough": {"rates": {**_CLEAN, "kissing": 0.4, "stub": 0.5, "hole": 0.3, "noise": 0.35, "staircase": 0.15,
                        "ragged_ends": 0.3, "inward_normals": 0.15, "inconsistent_orientation": 0.15, "components": 0.2},
              "end_styles": {"open": 0.5, "flat": 0.3, "round": 0.2}, "units": {"mm": 0.6, "cm": 0.25, "m": 0.15},
              "formats": {"vtp": 0.6, "stl": 0.25, "ply": 0.15}},
}


@dataclass
class Vessel:
    """A generated vessel: surface (in its units), true skeleton and what it has."""

    vertices: np.ndarray
    faces: np.ndarray
    xyz: np.ndarray
    radius: np.ndarray
    tags: list
    edges: np.ndarray
    manifest: dict = field(default_factory=dict)


def _choice(rng, table: dict) -> str:
    keys = list(table)
    w = np.array([table[k] for k in keys], float)
    return keys[int(rng.choice(len(keys), p=w / w.sum()))]


def draw_features(rng, rates: dict) -> set[str]:
    """The features one vessel gets (each with probability ``rates[name]``)."""
    u = rng.uniform(size=len(FEATURES))
    return {f for f, x in zip(FEATURES, u) if x < rates.get(f, 0.0)}


def _grow_component(rng, morph, wanted, origin, radius):
    """One tree with the features in ``wanted`` placed (those that found room)."""
    p = {**morph, "generations": int(rng.integers(morph["generations"][0], morph["generations"][1] + 1)),
         "pending": [f for f in JUNCTION_FEATURES if f in wanted]}
    tree = T.grow(p, rng, origin=origin, direction=T.unit(rng.normal([0, 0, 1], 0.2)), root_radius=radius)
    for f in ("large_ratio", "stub"):
        if f in wanted:
            T.add_side_branch(tree, rng, "side" if f == "large_ratio" else "stub", p)
    if "stub" in wanted and rng.uniform() < 0.5:
        T.add_side_branch(tree, rng, "stub", p)
    if "loop" in wanted:
        T.add_loop(tree, rng)
    for f in ("stenosis", "fusiform", "radius_jump"):
        if f in wanted:
            # a stenosis narrows one of the largest vessels (its throat stays above 0.6 x min_radius)
            T.modulate_radius(tree, rng, f, 3.0 * morph["min_radius"] if f == "stenosis" else 0.0)
    for f in ("aneurysm_apex", "aneurysm_side"):
        if f in wanted:
            T.add_aneurysm(tree, rng, f.split("_")[1])
    if "kissing" in wanted:
        T.add_kissing(tree, rng)
    return tree


def _merge(trees: list) -> T.Tree:
    """Several trees as one (branch indices shifted)."""
    out = T.Tree()
    for tr in trees:
        off = len(out.branches)
        for b in tr.branches:
            b.parent = b.parent + off if b.parent >= 0 else -1
            b.end_on = (b.end_on[0] + off, b.end_on[1]) if b.end_on is not None else None
            out.branches.append(b)
        out.sacs += tr.sacs
        out.features.update(tr.features)
    return out


def build_tree(rng, morph: dict, wanted: set) -> T.Tree:
    """The tree of one vessel: one component, or 2-3 side by side (``components``)."""
    n_comp = int(rng.integers(2, 4)) if "components" in wanted else 1
    trees = []
    for c in range(n_comp):
        r = morph["root_radius"] * (1.0 if c == 0 else rng.uniform(0.6, 0.85))
        tr = _grow_component(rng, morph, wanted if c == 0 else set(), np.zeros(3), r)
        if trees:  # beside the previous pieces, 3 root radii apart
            prev = np.concatenate([b.pts + 0 for t in trees for b in t.branches])
            P, R, _ = tr.points()
            shift = prev[:, 0].max() - (P[:, 0] - R).min() + 3 * morph["root_radius"] + R.max()
            for b in tr.branches:
                b.pts = b.pts + [shift, 0, 0]
            tr.sacs = [(cc + [shift, 0, 0], rr, bb) for cc, rr, bb in tr.sacs]
        trees.append(tr)
    tree = _merge(trees)
    if n_comp > 1:
        tree.features["components"] = n_comp
    return tree


def generate_vessel(seed=0, preset: str = "clean", rates: dict | None = None, end_style: str | None = None,
                    units: str | None = None, surface_format: str | None = None, grid_per_radius: float = 2.6,
                    max_voxels: float = 6e6, target_faces: tuple = (10_000, 100_000), morphology: dict | None = None,
                    name: str = "vessel") -> Vessel:
    """Generate one vessel.

    Parameters
    ----------
    seed : int or numpy.random.SeedSequence
        Everything random follows from it.
    preset : {"clean", "rough"}
        Default rates, end styles, units and file formats.
    rates : dict, optional
        Feature name -> probability, overriding the preset's.
    end_style : {"open", "flat", "round"}, optional
        Force the end style (default: drawn from the preset).
    units : {"mm", "cm", "m"}, optional
        Force the units (default: drawn from the preset).
    surface_format : {"vtp", "stl", "ply"}, optional
    grid_per_radius : float
        Grid samples across the smallest radius.
    max_voxels : float
        Grid budget; the spacing grows beyond it (then thin vessels are resolved coarser).
    target_faces : (int, int)
        The surface is decimated to a quarter of its contour's faces, clipped to this range.
    morphology : dict, optional
        Overrides of :data:`MORPHOLOGY`.

    Returns
    -------
    Vessel
    """
    t0 = time.perf_counter()
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rng = np.random.default_rng(ss)
    cfg = PRESETS[preset]
    wanted = draw_features(rng, {**cfg["rates"], **(rates or {})})
    # always drawn, so that forcing one of them leaves the geometry of the seed unchanged
    drawn = _choice(rng, cfg["end_styles"]), _choice(rng, cfg["units"]), _choice(rng, cfg["formats"])
    end_style, units, surface_format = end_style or drawn[0], units or drawn[1], surface_format or drawn[2]
    morph = {**MORPHOLOGY, **(morphology or {})}
    tree = build_tree(rng, morph, wanted)
    xyz, radius, tags, edges = T.skeleton_of(tree)
    caps = [(e, n, r) for _, e, n, r in S.end_caps(tree)]
    tag_ends(tree, xyz, tags, caps)

    h = S.grid_spacing(tree, grid_per_radius, max_voxels)
    F, grid = S.implicit_field(tree, end_style, h)
    feats = Counter(tree.features)
    if "noise" in wanted:
        P, R, _ = tree.points()
        F += S.noise_field(F.shape, h, 0.8 * float(R.mean()), rng.uniform(0.06, 0.12) * float(R.min()), rng)
        feats["noise"] = 1
    staircase = "staircase" in wanted
    V, Tri = S.contour(F, grid, staircase, smooth_iters=0)
    del F
    feats["staircase"] = int(staircase)
    V, Tri = finish_surface(V, Tri, caps, end_style, staircase, target_faces)
    if end_style == "open":
        if "ragged_ends" in wanted:
            V, Tri = S.ragged_cut(V, Tri, caps, rng)
            feats["ragged_ends"] = len(caps)
    P, R, _ = tree.points()
    if "hole" in wanted:
        junctions = xyz[np.bincount(edges.ravel(), minlength=len(xyz)) != 2]
        V, Tri, holes = S.punch_holes(V, Tri, int(rng.integers(1, 4)), P, R, junctions, rng)
        feats["hole"] = len(holes)
    if "inward_normals" in wanted:
        Tri = Tri[:, ::-1].copy()
        feats["inward_normals"] = 1
    if "inconsistent_orientation" in wanted:
        Tri = S.flip_patch(V, Tri, rng, P, R)
        feats["inconsistent_orientation"] = 1
    scale = UNITS[units]
    closed = end_style != "open" and not feats["hole"]
    manifest = {
        "name": name, "preset": preset, "seed_entropy": str(ss.entropy), "spawn_key": list(ss.spawn_key),
        "units": units, "unit_scale_per_mm": scale, "end_style": end_style, "surface_format": surface_format,
        "features": {f: int(feats.get(f, 0)) for f in FEATURES}, "requested": sorted(wanted),
        "closed": bool(closed), "outward": "inward_normals" not in wanted,
        "consistently_oriented": "inconsistent_orientation" not in wanted,
        "components": int(feats.get("components", 0)) or 1,
        "skeleton_nodes": int(len(xyz)), "skeleton_edges": int(len(edges)), "faces": int(len(Tri)),
        "vertices": int(len(V)), "grid_h_mm": round(h, 5), "min_radius_mm": round(float(R.min()), 4),
        "seconds": round(time.perf_counter() - t0, 2),
    }
    return Vessel(V * scale, Tri, xyz * scale, radius * scale, tags, edges, manifest)


def finish_surface(V, Tri, caps, end_style: str, staircase: bool = False, target_faces: tuple = (10_000, 100_000)):
    """A contour of a vessel's implicit field made its surface: open ends' flat discs removed,
    smoothed (unless a staircase), decimated to a quarter of its faces within
    ``target_faces``, flat and open ends snapped onto their cap planes."""
    if end_style == "open":  # the contour's flat end discs are exact: remove them before smoothing
        V, Tri = S.remove_faces(V, Tri, S.cap_faces(V, Tri, caps, 1e-3))
    if not staircase:
        V = S.smooth(V, Tri)
    target = int(np.clip(len(Tri) // 4, *target_faces))
    V, Tri = S.decimate(V, Tri, min(target, len(Tri)))
    if end_style in ("open", "flat"):
        V = S.snap_to_caps(V, caps, 0.05)
    return V, Tri


def tag_ends(tree, xyz, tags, caps):
    """``inlet`` on each root's start node, ``outlet`` on the other free ends."""
    roots = [b.pts[0] for b in tree.branches if b.parent < 0]
    for e, _, _ in caps:
        i = int(np.argmin(np.linalg.norm(xyz - e, axis=1)))
        tags[i] = tags[i] + (["inlet"] if any(np.allclose(e, r) for r in roots) else ["outlet"])


# ---------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------
def stub_vessel(angle: float = 70.0, ratio: float = 0.45, length: float = 1.5, end_style: str = "open",
                half: float = 8.0, name: str = "stub") -> Vessel:
    """A straight vessel of radius 1 mm along x (ends at +-``half``) with one stub, made as
    :func:`~data_synthetic.vessels.tree.add_side_branch` makes a ``stub``: radius ``ratio``,
    leaving the parent's axis at ``angle`` degrees from +x and cut ``length`` of its radii past
    the parent's wall; surface by the generator's own pipeline (contour, ends, smoothing,
    decimation). For sweeps over the stub's shape (issue 17).

    Parameters
    ----------
    angle : float
        Degrees between the stub's axis and the parent's (+x), in the xy plane.
    ratio : float
        The stub's radius, as a fraction of the parent's (1 mm).
    length : float
        How far the stub reaches past the parent's wall, in stub radii.
    end_style : {"open", "flat", "round"}
        The ends' style, as :func:`generate_vessel`'s.
    half : float
        Half the parent's length, mm.
    name : str
        The vessel's name in its manifest.

    Returns
    -------
    Vessel
        Surface, centerline (nodes, radii, tags, edges) and a manifest whose ``stub`` entry
        records ``angle``, ``ratio`` and ``length``.
    """
    parent = T.straight(np.array([-half, 0.0, 0.0]), np.array([half, 0.0, 0.0]), 1.0, 1.0)
    tree = T.Tree([T.Branch(*parent)])
    i = int(np.argmin(np.abs(parent[0][:, 0])))
    d = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
    tree.branches.append(T.Branch(*T.straight(parent[0][i], parent[0][i] + (1.0 + length * ratio) * d, ratio, ratio), 0, i, kind="stub"))
    tree.features["stub"] = 1
    return _made_as_the_corpus(tree, end_style, name, "stub", {"angle": angle, "ratio": ratio, "length": length})


def fork_vessel(angles=(8.0, 9.0), radii=(1.5, 1.2, 1.1), length: float = 12.0, end_style: str = "flat",
                name: str = "fork") -> Vessel:
    """A parent vessel along x (10 mm up to the origin) forking into two straight daughters
    ``length`` long, ``angles`` degrees either side of +x in the xy plane, as the
    generator's ``acute_angle`` feature makes them (6-11 degrees): the daughters' lumens run
    fused several radii past the fork (issue 18, seed 0 g0006 extracted).

    Parameters
    ----------
    angles : (float, float)
        Degrees of each daughter from +x (towards +y, towards -y).
    radii : (float, float, float)
        The parent's and the daughters' radii, mm.
    length : float
        The daughters' length, mm.
    end_style : {"open", "flat", "round"}
    name : str

    Returns
    -------
    Vessel
        As :func:`stub_vessel`'s; the manifest's ``fork`` entry records ``angles`` and ``radii``.
    """
    parent = T.straight(np.array([-10.0, 0.0, 0.0]), np.zeros(3), radii[0], radii[0])
    tree = T.Tree([T.Branch(*parent)])
    for angle, radius, side in zip(angles, radii[1:], (1.0, -1.0)):
        d = np.array([np.cos(np.radians(angle)), side * np.sin(np.radians(angle)), 0.0])
        tree.branches.append(T.Branch(*T.straight(np.zeros(3), length * d, radius, radius), 0, len(parent[0]) - 1))
    tree.features["acute_angle"] = 1
    return _made_as_the_corpus(tree, end_style, name, "acute_angle", {"angles": list(angles), "radii": list(radii)})


def _made_as_the_corpus(tree, end_style: str, name: str, feature: str, record: dict) -> Vessel:
    """``tree``'s vessel by :func:`generate_vessel`'s surface pipeline without its random
    features (contour, ends, smoothing, decimation), so that a hand-made shape is made as the
    corpus makes it; the manifest records ``feature`` and, under its kind, ``record``."""
    xyz, radius, tags, edges = T.skeleton_of(tree)
    caps = [(e, n, r) for _, e, n, r in S.end_caps(tree)]
    tag_ends(tree, xyz, tags, caps)
    F, grid = S.implicit_field(tree, end_style, S.grid_spacing(tree, 2.6, 6e6))
    V, Tri = finish_surface(*S.contour(F, grid, False, smooth_iters=0), caps, end_style)
    manifest = {"name": name, "units": "mm", "unit_scale_per_mm": 1.0, "end_style": end_style, "surface_format": "vtp",
                "features": {f: int(f == feature) for f in FEATURES}, "requested": [feature], "closed": end_style != "open",
                "outward": True, "consistently_oriented": True, "components": 1, "skeleton_nodes": int(len(xyz)),
                "skeleton_edges": int(len(edges)), "faces": int(len(Tri)), "vertices": int(len(V)),
                "stub" if feature == "stub" else "fork": record}
    return Vessel(V, Tri, xyz, radius, tags, edges, manifest)


def write_vessel(vessel: Vessel, folder) -> dict:
    """Write a vessel's files into ``folder``; returns its manifest (with ``files``)."""
    import pyvista as pv

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    m = dict(vessel.manifest)
    fmt = m["surface_format"]
    surf = pv.PolyData(vessel.vertices, np.c_[np.full(len(vessel.faces), 3), vessel.faces].ravel())
    surf.save(str(folder / f"surface.{fmt}"), binary=True)
    files = {"surface": f"surface.{fmt}", "swc": "skeleton.swc", "swc_noradius": "skeleton_noradius.swc",
             "centerline_vtp": "centerline.vtp", "centerline_vtp_noradius": "centerline_noradius.vtp",
             "skeleton_json": "skeleton.json"}
    write_swc(folder / files["swc"], vessel)
    write_swc(folder / files["swc_noradius"], vessel, radii=False)
    write_vmtk_centerline(folder / files["centerline_vtp"], vessel)
    write_vmtk_centerline(folder / files["centerline_vtp_noradius"], vessel, radii=False)
    nodes = [{"id": i, "xyz": [round(float(c), 9) for c in p], "radius": round(float(r), 9), "tags": t}
             for i, (p, r, t) in enumerate(zip(vessel.xyz, vessel.radius, vessel.tags))]
    (folder / files["skeleton_json"]).write_text(json.dumps({"name": m["name"], "units": m["units"], "nodes": nodes,
                                                             "edges": vessel.edges.tolist()}))
    m["files"] = files
    m["folder"] = str(folder)
    (folder / "manifest.json").write_text(json.dumps(m, indent=1))
    return m


def _spanning_parents(n, edges, roots):
    """Breadth-first parent of every node from ``roots`` (-1 for roots); edges not in the
    spanning forest (loops) are returned apart."""
    nbr = [[] for _ in range(n)]
    for a, b in edges.tolist():
        nbr[a].append(b)
        nbr[b].append(a)
    parent = np.full(n, -2)
    order = []
    for r in roots:
        if parent[r] != -2:
            continue
        parent[r] = -1
        queue = [r]
        while queue:
            u = queue.pop(0)
            order.append(u)
            for v in nbr[u]:
                if parent[v] == -2:
                    parent[v] = u
                    queue.append(v)
    tree_edges = {(min(u, int(parent[u])), max(u, int(parent[u]))) for u in order if parent[u] >= 0}
    extra = [(a, b) for a, b in edges.tolist() if (min(a, b), max(a, b)) not in tree_edges]
    return parent, order, extra


def _roots(vessel) -> list[int]:
    inlets = [i for i, t in enumerate(vessel.tags) if "inlet" in t]
    return inlets + list(range(len(vessel.xyz)))  # unreached pieces start anywhere


def write_swc(path, vessel: Vessel, radii: bool = True) -> Path:
    """SWC (``id type x y z radius parent``), breadth first from the inlets; type 1 soma at
    inlets, 3 elsewhere; ``radii=False`` writes radius 0 (unknown)."""
    parent, order, extra = _spanning_parents(len(vessel.xyz), vessel.edges, _roots(vessel))
    new_id = {u: k + 1 for k, u in enumerate(order)}
    lines = [f"# vessel_generator {vessel.manifest.get('name', '')}, units {vessel.manifest.get('units', 'mm')}"]
    if extra:
        lines.append(f"# {len(extra)} loop segment(s) not representable in SWC: see skeleton.json")
    for u in order:
        r = vessel.radius[u] if radii else 0.0
        p = new_id[int(parent[u])] if parent[u] >= 0 else -1
        x, y, z = vessel.xyz[u]
        lines.append(f"{new_id[u]} {1 if parent[u] < 0 else 3} {x:.9g} {y:.9g} {z:.9g} {r:.9g} {p}")
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def write_vmtk_centerline(path, vessel: Vessel, radii: bool = True) -> Path:
    """VMTK-style centerlines: one polyline from the inlet of each piece to every other end
    node, and one around each loop (inlet -> one side of the ring -> the other side, back to
    the junction where that side starts)."""
    import pyvista as pv

    parent, order, extra = _spanning_parents(len(vessel.xyz), vessel.edges, _roots(vessel))
    deg = np.bincount(vessel.edges.ravel(), minlength=len(vessel.xyz))

    def to_root(u):
        path = [u]
        while parent[path[-1]] >= 0:
            path.append(int(parent[path[-1]]))
        return path[::-1]

    def down_to_junction(u):  # u and its ancestors up to the first junction (a loop's far side)
        path = [u]
        while deg[path[-1]] == 2 and parent[path[-1]] >= 0:
            path.append(int(parent[path[-1]]))
        return path

    paths = [to_root(u) for u in order if deg[u] == 1 and parent[u] >= 0]
    paths += [to_root(a) + down_to_junction(b) for a, b in extra]
    pts = np.concatenate([vessel.xyz[p] for p in paths])
    rad = np.concatenate([vessel.radius[p] for p in paths])
    sizes = [len(p) for p in paths]
    offsets = np.r_[0, np.cumsum(sizes)[:-1]]
    cells = np.concatenate([np.r_[n, o + np.arange(n)] for n, o in zip(sizes, offsets)])
    poly = pv.PolyData(pts, lines=cells)
    if radii:
        poly.point_data["MaximumInscribedSphereRadius"] = rad
    poly.save(str(path), binary=True)
    return Path(path)


# ---------------------------------------------------------------------------
# corpora
# ---------------------------------------------------------------------------
def vessel_seed(seed: int, index: int) -> np.random.SeedSequence:
    """Seed of vessel ``index`` of a corpus (independent of the corpus size)."""
    return np.random.SeedSequence(seed, spawn_key=(index,))


def generate_one(out, index: int, seed: int = 0, preset: str = "mixed", **kw) -> dict:
    """Generate and write vessel ``index`` of a corpus into ``out/g<index>`` (kept when its
    manifest is already there and matches); returns its manifest."""
    folder = Path(out) / f"g{index:04d}"
    ss = vessel_seed(seed, index)
    pick = preset
    if preset == "mixed":
        pick = "clean" if np.random.default_rng(vessel_seed(seed + 7919, index)).uniform() < 0.5 else "rough"
    done = folder / "manifest.json"
    if done.is_file():
        m = json.loads(done.read_text())
        if m.get("spawn_key") == list(ss.spawn_key) and m.get("seed_entropy") == str(ss.entropy) and m.get("preset") == pick:
            return m
    return write_vessel(generate_vessel(ss, pick, name=folder.name, **kw), folder)


def generate_corpus(out, n: int, seed: int = 0, preset: str = "mixed", progress: bool = True, **kw) -> list[dict]:
    """Generate ``n`` vessels into ``out`` and write ``out/manifest.json`` (all of them)."""
    out = Path(out)
    found = []
    for i in range(n):
        m = generate_one(out, i, seed, preset, **kw)
        found.append(m)
        if progress:
            on = [f for f, v in m["features"].items() if v]
            print(f"{m['name']}: {m['preset']}, {m['skeleton_nodes']} nodes, {m['faces']} faces, {m['units']}, "
                  f"{m['end_style']} ends, {m['seconds']} s; {', '.join(on) or 'no features'}", flush=True)
    (out / "manifest.json").write_text(json.dumps({"seed": seed, "preset": preset, "n": n, "vessels": found}, indent=1))
    return found


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m data_synthetic.vessel_generator", description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=10, help="number of vessels")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--preset", default="mixed", choices=["clean", "rough", "mixed"])
    ap.add_argument("--out", type=Path, required=True, help="output folder (one sub-folder per vessel)")
    ap.add_argument("--rate", action="append", default=[], metavar="FEATURE=P", help="override a feature rate (repeatable)")
    args = ap.parse_args(argv)
    rates = {}
    for item in args.rate:
        name, _, val = item.partition("=")
        if name not in FEATURES:
            print(f"vessel_generator: error: unknown feature '{name}' (choose from {', '.join(FEATURES)})", file=sys.stderr)
            return 2
        try:
            rates[name] = float(val)
        except ValueError:
            print(f"vessel_generator: error: rate of '{name}' is not a number: {val!r}", file=sys.stderr)
            return 2
    generate_corpus(args.out, args.n, args.seed, args.preset, rates=rates or None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
