"""The generated junctions of ``tests/test_junctions.py``, built and filled without untangling.

Each case is built as the test builds it (``separate_parallel_branches``, then
``build_blocks`` with the wall projection) and filled at the default chain's resolution;
the table gives the least and mean scaled Jacobian, the inverted elements and the block
building time. ``--set name=value`` changes a :class:`BlockOptions` field (e.g.
``--set junction_centre=0`` for the placement on the skeleton node); ``--cases`` picks
cases by name; ``--curved`` fills as ``mesh_transfinite`` does (curved cross-sections and
along-skeleton edges; ``--straight-along`` keeps the latter straight). ``--optimise`` adds
the least and mean scaled Jacobian after ``mesh_transfinite``'s untangling and light pass
(its defaults, as the default chain runs them; no exact first layer), so that a change
that helps the raw fill can be checked for what the optimisers make of it.

    python benchmarks/junction_sweep.py [--cases bif_30_2 trif_60_2] [--set junction_centre=0] [--curved [--straight-along]] [--optimise]
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import os
import sys
import time
import types

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

import test_junctions as tj  # noqa: E402

from vmesh.errors import MeshingError  # noqa: E402
from vmesh.geometry import skeleton_ops as ops  # noqa: E402
from vmesh.geometry import transfinite_curves as curves  # noqa: E402
from vmesh.geometry.block_builder import BlockOptions, build_blocks  # noqa: E402
from vmesh.geometry.quality import scaled_jacobian  # noqa: E402
from vmesh.geometry.transfinite import mesh_blocks  # noqa: E402


def optimised(case, blocks, ref) -> tuple:
    """Raw and optimised scaled Jacobians: the fill, then ``mesh_transfinite``'s untangling
    and light pass with their default parameters (a stub context takes their reports)."""
    from vmesh.filters.mesh_filters import _light_pass, _untangle

    sm = mesh_blocks(blocks, case.project, ref, signed_distance=case.distance)
    raw = scaled_jacobian(sm.points, sm.cells, ref.order)
    ctx = types.SimpleNamespace(tick=lambda *a, **k: None, count=lambda **k: None, report=types.SimpleNamespace(sections={}))
    sdf = types.SimpleNamespace(gradient=case.gradient)
    _untangle(ctx, sm, case.project, sdf, 0.3, 0.3)
    _light_pass(ctx, sm, case.project, sdf, 0.95, "gauss_lobatto")
    return raw, scaled_jacobian(sm.points, sm.cells, ref.order)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=None)
    ap.add_argument("--set", nargs="*", default=[], help="BlockOptions field=value")
    ap.add_argument("--curved", action="store_true", help="fill as mesh_transfinite does (curved sections and along-skeleton edges)")
    ap.add_argument("--straight-along", action="store_true", help="with --curved: keep the along-skeleton edges straight (the previous fill)")
    ap.add_argument("--optimise", action="store_true", help="also untangle and light-pass as mesh_transfinite does, and give the final min / mean")
    args = ap.parse_args()
    options = {}
    for item in args.set:
        key, value = item.split("=", 1)
        options[key] = ast.literal_eval(value)
    ref = dataclasses.replace(tj.DEFAULT, curved_sections=args.curved)
    if args.straight_along:
        curves.MAX_ALONG_TURN = 0.0
    print(f"options {options or 'default'}; curved {args.curved}, along edges {'straight' if args.straight_along or not args.curved else 'curved'}; load average {os.getloadavg()[0]:.1f}")
    final = f" {'opt min':>7s} {'mean':>6s}" if args.optimise else ""
    print(f"{'case':18s} {'blocks':>6s} {'SJ min':>7s} {'mean':>6s} {'inverted':>8s} {'build s':>7s}{final}")
    for name, (factory, fargs) in tj._cases():
        if args.cases and name not in args.cases:
            continue
        case = factory(*fargs)
        t = time.perf_counter()
        try:
            sk, _ = ops.separate_parallel_branches(case.skeleton, 30.0, 60.0, distance=case.distance)
            blocks = build_blocks(sk, case.distance, None, BlockOptions(**options), project=case.project)
        except MeshingError as exc:
            print(f"{name:18s} blocks invalid: {str(exc)[:90]}")
            continue
        seconds = time.perf_counter() - t
        if args.optimise:
            sj, opt = optimised(case, blocks, ref)
            final = f" {opt.min():7.3f} {opt.mean():6.3f}"
        else:
            sj, final = tj.fill(case, blocks, ref), ""
        print(f"{name:18s} {blocks.n_blocks:6d} {sj.min():7.3f} {sj.mean():6.3f} {int((sj <= 0).sum()):8d} {seconds:7.2f}{final}", flush=True)


if __name__ == "__main__":
    main()
