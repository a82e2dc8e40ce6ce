"""Where the inverted elements of one run sit after each stage of ``mesh_transfinite``.

Runs the default chain through ``build_block_structure`` (its context pickled to ``--prefix``
and reused when that file exists), then ``mesh_transfinite`` with hooks that record, for the
raw fill (before any optimiser), after the untanglers, after the light pass, the worst pass and
the second light pass ("light pass 2", when the worst pass moved a node): the inverted
elements, their blocks, skeleton nodes and block layers (0 core, 1 ring, 2 boundary layer),
how many lie in the blocks the builder flagged ("may fold when their faces are projected onto
the wall", ``blocks.info["wall_fold_blocks"]``), how many have wall nodes, and how many have
a node off the wall that lies outside the vessel (the wall passes through the element: no
move of the off-wall nodes alone restores it). Ends with the report's untangle section.

    PYTHONPATH=$PWD python3 benchmarks/fold_stages.py SURFACE [--skeleton FILE] --prefix /tmp/x.pkl [--json OUT]

docs/optimiser.md, "Where the untanglers' folds come from" (h15/folds).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402


def stage_row(ctx, sm, sdf) -> dict:
    """The inverted elements of the structured mesh ``sm`` now (see the module docstring)."""
    from vmesh.geometry.quality import scaled_jacobian

    blocks = ctx.blocks
    sj = scaled_jacobian(sm.points, sm.cells, sm.order)
    bad = np.flatnonzero(sj <= 0)
    b = sm.cell_block[bad]
    flagged = np.isin(b, np.asarray(blocks.info.get("wall_fold_blocks") or [], np.int64))
    nodes = sm.cells[bad]
    wall = sm.on_wall[nodes]
    f = np.asarray(sdf.fine.distance(sm.points[nodes].reshape(-1, 3))).reshape(wall.shape) if len(bad) else np.zeros(wall.shape)
    outside = (np.where(wall, np.inf, f) < 0).any(axis=1)
    return {
        "min": round(float(sj.min()), 4), "mean": round(float(sj.mean()), 4), "inverted": int(len(bad)), "below_0.3": int((sj < 0.3).sum()),
        "blocks": sorted(set(b.tolist())), "skeleton_nodes": sorted(set(blocks.block_node[b].tolist())),
        "per_layer": np.bincount(blocks.block_layer[b], minlength=3).tolist(), "in_flagged_blocks": int(flagged.sum()),
        "with_wall_nodes": int(wall.any(axis=1).sum()), "off_wall_node_outside": int(outside.sum()),
    }


def prefix_context(surface, skeleton, path: Path):
    """The context after the steps before ``mesh_transfinite`` (pickled to ``path`` with the
    input paths; a pickle written for other inputs is refused)."""
    from vmesh.chain import FilterChain
    from vmesh.context import Context
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    inputs = {"surface": str(Path(surface).resolve()), "skeleton": str(Path(skeleton).resolve()) if skeleton else None}
    if path.is_file():
        saved = pickle.loads(path.read_bytes())
        if not isinstance(saved, dict) or saved.get("inputs") != inputs:
            got = saved.get("inputs") if isinstance(saved, dict) else "unknown (an older pickle)"
            raise SystemExit(f"--prefix {path} was written for other inputs ({got}); not {inputs}: remove it or pass another --prefix")
        return saved["context"]
    chain = FilterChain.load("default").with_overrides(C.BENCH_OVERRIDES)
    chain.steps = chain.steps[: [s.filter for s in chain.steps].index("mesh_transfinite")]
    ctx = Context()
    chain.run(surface=read_surface(surface), skeleton=read_skeleton(skeleton) if skeleton else None, out_dir=None, context=ctx)
    path.write_bytes(pickle.dumps({"inputs": inputs, "context": ctx}))
    return ctx


def prefix_arguments(description: str, json_help: str) -> argparse.ArgumentParser:
    """The command line of the scripts that work on a chain's context before
    ``mesh_transfinite``: a surface, an optional centerline, the prefix pickle, a JSON output."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("surface")
    ap.add_argument("--skeleton", help="a given centerline (default: extracted)")
    ap.add_argument("--prefix", required=True, help="pickle of the chain's context before mesh_transfinite (written once)")
    ap.add_argument("--json", help=json_help)
    return ap


def main(argv=None) -> int:
    args = prefix_arguments(__doc__.splitlines()[0], "write the stages and the untangle section here").parse_args(argv)
    import vmesh.filters.mesh_filters as mf
    from vmesh.chain import FilterChain
    from vmesh.registry import get_filter

    ctx = prefix_context(args.surface, args.skeleton, Path(args.prefix))
    rows = {}
    untangle, light, worst = mf._untangle, mf._light_pass, mf._worst_pass

    def hooked_untangle(ctx_, sm, projector, sdf, *a, **kw):
        rows["raw fill"] = stage_row(ctx_, sm, sdf)
        out = untangle(ctx_, sm, projector, sdf, *a, **kw)
        rows["untanglers"] = stage_row(ctx_, sm, sdf)
        return out

    def hooked_light(ctx_, sm, projector, sdf, *a, **kw):
        out = light(ctx_, sm, projector, sdf, *a, **kw)
        rows["light pass 2" if "light pass" in rows else "light pass"] = stage_row(ctx_, sm, sdf)
        return out

    def hooked_worst(ctx_, sm, projector, sdf, *a, **kw):
        out = worst(ctx_, sm, projector, sdf, *a, **kw)
        rows["worst pass"] = stage_row(ctx_, sm, sdf)
        return out

    mf._untangle, mf._light_pass, mf._worst_pass = hooked_untangle, hooked_light, hooked_worst
    try:
        step = next(s for s in FilterChain.load("default").steps if s.filter == "mesh_transfinite")
        t0 = time.perf_counter()
        get_filter("mesh_transfinite")(ctx, **step.params)
    finally:
        mf._untangle, mf._light_pass, mf._worst_pass = untangle, light, worst
    for name, row in rows.items():
        print(f"{name:12s} {json.dumps(row)}")
    section = ctx.report.sections.get("untangle", {})
    n = len(ctx.mesh.points)
    print(f"mesh_transfinite {time.perf_counter() - t0:.1f} s; {n} nodes; untangle: moved {section.get('moved')} "
          f"({100 * int(section.get('moved') or 0) / n:.1f} %), rounds {section.get('rounds')}, local untangler's min "
          f"{section.get('after_local_min')}, restart {section.get('restart')}, work {section.get('work')}")
    if args.json:
        Path(args.json).write_text(json.dumps({"stages": rows, "nodes": n, "untangle": section,
                                               "light_pass": ctx.report.sections.get("light_pass"), "worst_pass": ctx.report.sections.get("worst_pass"),
                                               "light_pass_after_worst": ctx.report.sections.get("light_pass_after_worst")}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
