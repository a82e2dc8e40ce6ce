"""Every trial of the poor-block lift (``build_block_structure.poor_block_sj``) of one run,
with what each criterion sees: the structure's least corner scaled Jacobian and the summed
shortfall below the floor (what the lift judges by), and the raw transfinite fill (without
untangling, at each resolution of ``blocks.checks.FILL_CHECKS``) of the blocks the trial
moved, least and mean element, before and after (what a fill-judged lift would see). With
``--mesh`` the rest of the chain runs and the mesh's least and mean scaled Jacobian are
printed, so a criterion can be compared with the run's result.

    PYTHONPATH=$PWD python3 benchmarks/poor_rounds.py SURFACE [--skeleton FILE] --prefix /tmp/x.pkl [--floor 0.3] [--mesh] [--optimised] [--json OUT]

The chain's steps before ``build_block_structure`` run once and are pickled to ``--prefix``
(reused when it exists: remove it for other inputs). With ``--optimised`` the rounds are judged by
the moved blocks' optimised fill (``poor_block_optimised``), printed under each trial.
docs/optimiser.md, h25/minima and h26/minima.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("surface")
    ap.add_argument("--skeleton")
    ap.add_argument("--prefix", required=True, help="pickle of the context before build_block_structure (written when missing)")
    ap.add_argument("--floor", type=float, default=0.3, help="build_block_structure.poor_block_sj")
    ap.add_argument("--mesh", action="store_true", help="run mesh_transfinite and compute_quality too")
    ap.add_argument("--optimised", action="store_true", help="judge the rounds by the moved blocks' optimised fill (build_block_structure.poor_block_optimised)")
    ap.add_argument("--json", help="write the trials (and the mesh's quality) here")
    a = ap.parse_args(argv)

    import vmesh.geometry.blocks.poor as poor
    from vmesh.chain import FilterChain
    from vmesh.context import Context
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    chain = FilterChain.load("default").with_overrides({**C.BENCH_OVERRIDES, "build_block_structure.poor_block_sj": a.floor,
                                                      "build_block_structure.poor_block_optimised": a.optimised})
    names = [s.filter for s in chain.steps]
    path = Path(a.prefix)
    if path.is_file():
        ctx = pickle.loads(path.read_bytes())
    else:
        head = FilterChain.load("default").with_overrides(C.BENCH_OVERRIDES)
        head.steps = head.steps[: names.index("build_block_structure")]
        ctx = Context()
        head.run(surface=read_surface(a.surface), skeleton=read_skeleton(a.skeleton) if a.skeleton else None, out_dir=None, context=ctx)
        path.write_bytes(pickle.dumps(ctx))
    first = names.index("build_block_structure")
    chain.steps = chain.steps[first: names.index("compute_quality") + 1] if a.mesh else chain.steps[first: first + 1]
    poor.TRIAL_LOG = []
    chain.run(context=ctx, out_dir=None)
    out = {"trials": poor.TRIAL_LOG}
    print("nodes    repair               kept  least block      shortfall        moved  fill before (least/mean per resolution) -> after")
    for t in poor.TRIAL_LOG:
        lb = "%.3f -> %s" % (t["least_block"][0], "-" if t["least_block"][1] is None else "%.3f" % t["least_block"][1])
        sf = "%.2f -> %s" % (t["shortfall"][0], "-" if t["shortfall"][1] is None else "%.2f" % t["shortfall"][1])
        fill = f"{t['fill_before']} -> {t['fill_after']}" if "moved" in t else "(not built or invalid)"
        print(f"{str(t['nodes']):8s} {t['repair']:20s} {str(t['kept']):5s} {lb:16s} {sf:16s} {t.get('moved', '-')!s:6s} {fill}")
        if t.get("optimised"):
            o = t["optimised"]
            print(f"{'':8s} optimised fill of {o['moved']} moved block(s): {o.get('before')} -> {o.get('after')}")
    if a.mesh:
        from vmesh.geometry.quality import scaled_jacobian

        q = scaled_jacobian(ctx.mesh.points, ctx.mesh.cells, ctx.mesh.order)
        out["mesh"] = {"sj_min": float(q.min()), "sj_mean": float(q.mean()), "elements": int(len(q))}
        print(f"mesh: min {q.min():.4f} mean {q.mean():.4f} elements {len(q)}")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
