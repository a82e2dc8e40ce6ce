"""Where the elements below the pass line (scaled Jacobian 0.3) of one run sit, stage by stage.

Runs the default chain through ``build_block_structure`` (its context pickled to ``--prefix``
and reused when that file exists, as :mod:`fold_stages`), then ``mesh_transfinite`` with hooks
that keep every element's scaled Jacobian after the raw fill (before any optimiser), the
untanglers, the light pass, the worst pass and the second light pass. Prints per stage the
minimum, mean and the counts inverted / below 0.3; then the run's worst elements with their
block, skeleton node (and its degree), segment, block layer (0 core, 1 ring, 2 boundary layer),
whether the builder flagged the block ("may fold when their faces are projected onto the wall"),
how many of its nodes lie on the wall, the straight block's own least corner scaled Jacobian
(before the fill) and the element's value at each stage; and the elements below 0.3 per
(skeleton node, layer). ``--set PARAM=VALUE`` overrides a ``mesh_transfinite`` parameter.

    PYTHONPATH=$PWD python3 benchmarks/low_stages.py SURFACE [--skeleton FILE] --prefix /tmp/x.pkl [--set worst_pass_sweeps=0]

docs/optimiser.md, "Runs that fail only on their minimum" (session 23, h23/minima).
"""

from __future__ import annotations

import copy
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fold_stages as FS  # noqa: E402

#: the pass line of the robustness benchmark (issue 17)
PASS_MIN = 0.3
#: VTK corner order of the block hexahedra -> tensor order (corner i + 2 j + 4 k)
VTK_TO_TENSOR = [0, 1, 3, 2, 4, 5, 7, 6]


def main(argv=None) -> int:
    ap = FS.prefix_arguments(__doc__.splitlines()[0], "write the per-stage summary here")
    ap.add_argument("--set", action="append", default=[], help="mesh_transfinite parameter override, PARAM=VALUE (JSON value)")
    ap.add_argument("--worst", type=int, default=20, help="how many of the worst elements to list")
    args = ap.parse_args(argv)
    import vmesh.filters.mesh_filters as mf
    from vmesh.chain import FilterChain
    from vmesh.geometry.quality import hex8_scaled_jacobian, scaled_jacobian
    from vmesh.registry import get_filter

    ctx = copy.deepcopy(FS.prefix_context(args.surface, args.skeleton, Path(args.prefix)))
    blocks = ctx.blocks
    stages: dict[str, np.ndarray] = {}

    def keep(name, sm):
        stages[name] = scaled_jacobian(sm.points, sm.cells, sm.order).copy()

    untangle, light, worst = mf._untangle, mf._light_pass, mf._worst_pass

    def hooked_untangle(ctx_, sm, *a, **kw):
        keep("raw fill", sm)
        out = untangle(ctx_, sm, *a, **kw)
        keep("untanglers", sm)
        return out

    def hooked_light(ctx_, sm, *a, **kw):
        out = light(ctx_, sm, *a, **kw)
        keep("light pass 2" if "light pass" in stages else "light pass", sm)
        return out

    def hooked_worst(ctx_, sm, *a, **kw):
        out = worst(ctx_, sm, *a, **kw)
        keep("worst pass", sm)
        return out

    params = dict(next(s for s in FilterChain.load("default").steps if s.filter == "mesh_transfinite").params)
    for kv in args.set:
        key, value = kv.split("=", 1)
        params[key.split(".")[-1]] = json.loads(value)
    mf._untangle, mf._light_pass, mf._worst_pass = hooked_untangle, hooked_light, hooked_worst
    try:
        t0 = time.perf_counter()
        get_filter("mesh_transfinite")(ctx, **params)
        seconds = time.perf_counter() - t0
    finally:
        mf._untangle, mf._light_pass, mf._worst_pass = untangle, light, worst
    mesh = ctx.mesh
    cd = mesh.cell_data
    stages["final"] = scaled_jacobian(mesh.points, mesh.cells, mesh.order)
    final = stages["final"]
    summary = {name: {"min": round(float(q.min()), 4), "mean": round(float(q.mean()), 4), "inverted": int((q <= 0).sum()),
                      f"below_{PASS_MIN}": int((q < PASS_MIN).sum())} for name, q in stages.items()}
    print(f"mesh_transfinite {seconds:.1f} s")
    for name, row in summary.items():
        print(f"  {name:13s} {json.dumps(row)}")
    degree = np.bincount(np.asarray(ctx.skeleton.edges).ravel(), minlength=len(ctx.skeleton.points))
    flagged = set(blocks.info.get("wall_fold_blocks") or [])
    block_sj = hex8_scaled_jacobian(blocks.vertices, blocks.hexes[:, VTK_TO_TENSOR])
    low = np.flatnonzero(final < PASS_MIN)
    print("  worst elements: cell, block, node (degree), segment, layer, flagged, wall nodes, block's own SJ | " + ", ".join(stages))
    for c in np.argsort(final)[: args.worst]:
        b, n = int(cd["block_id"][c]), int(cd["node_id"][c])
        deg = int(degree[n]) if n < len(degree) else -1
        print(f"    {c} b{b} n{n}({deg}) s{int(cd['segment_id'][c])} L{int(cd['layer'][c])} {'F' if b in flagged else '-'} "
              f"w{int(mesh.on_wall[mesh.cells[c]].sum())} {block_sj[b]:.3f} | " + " ".join(f"{q[c]:.3f}" for q in stages.values()))
    by_node = Counter((int(cd["node_id"][c]), int(cd["layer"][c])) for c in low)
    print(f"  below {PASS_MIN} by (node, layer): {by_node.most_common(12)}")
    if args.json:
        Path(args.json).write_text(json.dumps({"stages": summary, "below_by_node_layer": [[list(k), v] for k, v in by_node.most_common()]}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
