"""Close junction pairs of the skeleton that reaches the block builder, measured.

Runs the default chain up to ``build_block_structure`` on one surface (and optional
centerline), lists every branch between two junctions shorter than ``--within`` radii
(the larger junction's) with its junctions' degrees, radii, branch angles and radii, then
builds with every builder try traced: per pair the first try's half-section reaches
(``_junction_reach`` from each end) against the branch's length, which tries fail and at
which pairs their invalid blocks sit, and what ``merge_junction_pair`` makes of a pair.
Per pair also the cleaning's pair rule (:func:`_crossing`, from
:mod:`vmesh.geometry.skeleton.pairs`): the crossing margin of each junction's view and
whether the pair is blockable.

    PYTHONPATH=$PWD nice python3 benchmarks/junction_pairs.py SURFACE [SKELETON|-] [--set k=v ...]
    PYTHONPATH=$PWD nice python3 benchmarks/junction_pairs.py --fan 4 45        # tests' fan, separated
    PYTHONPATH=$PWD nice python3 benchmarks/junction_pairs.py --close 1.0 20 10 # close_junctions, separated
    PYTHONPATH=$PWD nice python3 benchmarks/junction_pairs.py --pair 0.9 20 -20 50

The generated vessels are built with ``build_blocks`` directly (``BlockOptions()``), the
surfaces with the default chain. See docs/junctions.md.

Diagnosis only; prints, writes nothing.
"""
from __future__ import annotations

import argparse
import itertools

import numpy as np


def _branch_dir(sk, path, r_ahead):
    """Direction from a branch's first node to the point ``r_ahead`` along it, and the
    radius there."""
    P = sk.points[path]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    k = int(min(np.searchsorted(arc, r_ahead), len(path) - 1))
    d = P[k] - P[0]
    return d / max(np.linalg.norm(d), 1e-300), float(sk.radii[path[k]]), float(arc[-1])


def _angle(u, v):
    from vmesh.geometry.skeleton.graph import vector_angle

    return float(np.degrees(vector_angle(np.asarray(u), np.asarray(v))))


def _crossing(sk, paths, a, b):
    """The pair rule of the cleaning on the pair, both ways round: per near junction the
    crossing margin (:func:`vmesh.geometry.skeleton.pairs.pair_margin`, degrees; under 0 a
    daughter of the far junction runs across the near junction's half-plane between the
    link and a sibling) and whether :func:`~vmesh.geometry.skeleton.pairs.blockable_pair`
    holds."""
    from vmesh.geometry.skeleton.pairs import blockable_pair, pair_margin

    out = []
    for near, far in ((a, b), (b, a)):
        m = pair_margin(sk, near, far, paths)
        out.append(f"near {near}: margin {m:+.0f} deg, {'CROSSES' if m < 0 else 'inside'}, "
                   f"{'blockable' if blockable_pair(sk, near, far, paths) else 'not blockable'}")
    return "; ".join(out)


def describe_pairs(sk, within=2.5):
    """``[(a, b, path, text)]`` for branches between two junctions shorter than ``within``
    x the larger junction radius."""
    from vmesh.geometry.skeleton.graph import branch_paths

    deg = sk.degrees
    paths = branch_paths(sk.n_nodes, sk.edges)
    out = []
    for p in paths:
        a, b = int(p[0]), int(p[-1])
        if a == b or deg[a] < 3 or deg[b] < 3:
            continue
        L = float(np.linalg.norm(np.diff(sk.points[p], axis=0), axis=1).sum())
        r = float(max(sk.radii[a], sk.radii[b]))
        if L >= within * r:
            continue
        normals = {}
        for c in (a, b):
            own = [q if int(q[0]) == c else q[::-1] for q in paths if c in (int(q[0]), int(q[-1]))]
            U = np.array([_branch_dir(sk, q, float(sk.radii[c]))[0] for q in own])
            normals[c] = np.linalg.svd(U - U.mean(0))[2][-1]
        dihedral = _angle(normals[a], normals[b])
        dihedral = min(dihedral, 180.0 - dihedral)
        lines = [f"pair {a} (deg {deg[a]}, r {sk.radii[a]:.2f}) - {b} (deg {deg[b]}, r {sk.radii[b]:.2f}): "
                 f"length {L:.2f} = {L / r:.2f} r, straight {np.linalg.norm(sk.points[a] - sk.points[b]) / r:.2f} r, planes {dihedral:.0f} deg apart"]
        for c in (a, b):
            rc = float(sk.radii[c])
            own = [q if int(q[0]) == c else q[::-1] for q in paths if c in (int(q[0]), int(q[-1]))]
            dirs = []
            for q in own:
                u, rq, lq = _branch_dir(sk, q, rc)
                link = {int(q[0]), int(q[-1])} == {a, b}
                dirs.append((u, rq, lq, int(q[-1]), link))
            U = np.array([d[0] for d in dirs])
            planar = np.linalg.svd(U - U.mean(0), compute_uv=False)[-1] if len(U) >= 3 else 0.0
            link_u = next(d[0] for d in dirs if d[4])
            desc = ", ".join(f"{'*' if d[4] else ''}->{d[3]} r {d[1]:.2f} ({d[1] / rc:.2f}) L {d[2] / rc:.1f}r "
                             f"{_angle(link_u, d[0]):.0f}deg" for d in dirs)
            pair_angles = sorted(_angle(x[0], y[0]) for x, y in itertools.combinations(dirs, 2))
            lines.append(f"   at {c}: {desc}; min pair angle {pair_angles[0]:.0f}, non-planarity {planar:.2f}")
        lines.append("   " + _crossing(sk, paths, a, b))
        out.append((a, b, p, "\n".join(lines)))
    return out


def _synthetic_case(args):
    """The separated skeleton of the ``--fan`` / ``--pair`` / ``--close`` case and a
    function building its blocks; ``(None, None)`` for a surface."""
    if not (args.fan or args.close or args.pair):
        return None, None
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from junction_cases import close_junctions, fan, junction_pair
    from vmesh.geometry import skeleton_ops as ops
    from vmesh.geometry.block_builder import BlockOptions, build_blocks
    if args.fan:
        case = fan(int(args.fan[0]), args.fan[1])
    elif args.pair:
        case = junction_pair(*args.pair)
    else:
        case = close_junctions(args.close[0], side=(args.close[1], args.close[2]))
    sk, moved = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
    print(f"{case.name}: separate_parallel_branches moved {moved}; {sk.n_nodes} nodes, {len(sk.junctions)} junctions")
    return sk, lambda: build_blocks(sk, case.distance, None, BlockOptions(), project=case.project, warn=lambda m: None)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("surface", nargs="?", help="surface file (none with --fan / --close / --pair)")
    ap.add_argument("skeleton", nargs="?", default="-")
    ap.add_argument("--fan", nargs=2, type=float, metavar=("N", "SPREAD"), help="tests' planar fan, separated as clean_skeleton does")
    ap.add_argument("--pair", nargs=4, type=float, metavar=("GAP", "A1", "A2", "SIDE"),
                    help="a side-branch junction (side branch at azimuth SIDE) and, GAP radii on, a junction with daughters at azimuths A1, A2 (all in one plane)")
    ap.add_argument("--close", nargs=3, type=float, metavar=("GAP", "AZ", "EL"), help="junction_cases.close_junctions, separated")
    ap.add_argument("--set", action="append", default=[], help="chain option key=value (as vmesh run --set)")
    ap.add_argument("--within", type=float, default=2.5, help="pairs shorter than this x radius")
    args = ap.parse_args(argv)

    from vmesh.chain import FilterChain
    import vmesh.geometry.blocks.builder as B
    from vmesh.geometry.blocks import merge_junction_pair
    from vmesh.geometry.blocks.options import JUNCTION

    sk, build = _synthetic_case(args)
    chain = FilterChain.load("default")
    if args.set:
        import json
        def val(v):
            try:
                return json.loads(v)
            except ValueError:
                return v
        chain = chain.with_overrides({kv.partition("=")[0]: val(kv.partition("=")[2]) for kv in args.set})
    steps = [s.filter for s in chain.steps]
    k = steps.index("build_block_structure")
    if sk is None:
        ctx = FilterChain(chain.steps[:k]).run(surface=args.surface, skeleton=None if args.skeleton == "-" else args.skeleton)
        sk = ctx.skeleton
    print(f"skeleton to the builder: {sk.n_nodes} nodes, {len(sk.junctions)} junctions")
    pairs = describe_pairs(sk, args.within)
    for a, b, p, text in pairs:
        print(text)
        merged, node = merge_junction_pair(sk, a, b)
        print(f"   merged: node {node} deg {merged.degrees[node]} r {merged.radii[node]:.2f}, "
              f"{np.linalg.norm(merged.points[node] - sk.points[a]) / sk.radii[a]:.2f} r from {a}, "
              f"{np.linalg.norm(merged.points[node] - sk.points[b]) / sk.radii[b]:.2f} r from {b}")

    n_try, printed = [0], set()
    orig_run, orig_clear = B._Builder.run, B._Builder._apply_clearance

    def clear(self):
        orig_clear(self)
        if n_try[0] in printed:  # the first placement of each try only
            return
        printed.add(n_try[0])
        for bi, br in enumerate(self.topo.branches):
            if br.kinds == [JUNCTION, JUNCTION] and br.nodes[0] != br.nodes[-1]:
                a, b = int(br.nodes[0]), int(br.nodes[-1])
                sk_ = self.topo.sk
                r = max(sk_.radii[a], sk_.radii[b])
                if br.arc[-1] < args.within * r:
                    ra, rb = self._junction_reach(bi, 0), self._junction_reach(bi, 1)
                    print(f"   try {n_try[0]} branch {a}-{b}: length {br.arc[-1]:.2f}, reach from {a} {ra:.2f} "
                          f"({ra / sk_.radii[a]:.2f} r), from {b} {rb:.2f} ({rb / sk_.radii[b]:.2f} r), slack {self._slack(bi):.2f}"
                          f"{' CROWDED' if bi in self.topo.crowded else ''}")

    def run(self):
        n_try[0] += 1
        sk_ = self.topo.sk
        tag = f"try {n_try[0]}: nodes {sk_.n_nodes} junctions {len(sk_.junctions)} centre {self.opt.junction.junction_centre} lean {self.opt.junction.junction_lean}"
        try:
            out = orig_run(self)
            print("TRY ok", tag, flush=True)
            return out
        except Exception as e:
            bad = getattr(e, "bad", None)
            where = {}
            if bad is not None and len(bad):
                J = e.blocks.corner_jacobians().min(axis=1)
                for blk in bad.tolist():
                    br = self.topo.branches[int(self.built.block_where[blk, 0])]
                    key = (int(br.nodes[0]), int(br.nodes[-1]))
                    n, w = where.get(key, (0, 0.0))
                    where[key] = (n + 1, min(w, float(J[blk])))
            print("TRY fail", tag, ":", str(e)[:160], "| bad by branch", {k: (n, round(w, 2)) for k, (n, w) in where.items()},
                  "| crowded", getattr(e, "crowded", None), "nfurc", getattr(e, "nfurcations", None), flush=True)
            raise

    B._Builder.run, B._Builder._apply_clearance = run, clear
    try:
        if build is not None:
            info = build().info
        else:
            info = FilterChain([chain.steps[k]]).run(context=ctx).blocks.info
        print("FINAL ok;", "; ".join(info.get("fixes", [])[:6]))
    except Exception as e:
        print("FINAL fail", str(e)[:300])
    finally:
        B._Builder.run, B._Builder._apply_clearance = orig_run, orig_clear


if __name__ == "__main__":
    main()
