"""The generator's stub on a straight vessel (``data_synthetic.vessel_generator.stub_vessel``)
swept over its angle, radius ratio and length, each through the default chain with its true
centerline (issue 17, docs/junctions.md).

One row per vessel: the result (min / mean scaled Jacobian, or the failing step and error),
the stubs the builder cut back into their parent, and the holes repair_surface filled (a
stub's open end taken for a hole shows there).

    python benchmarks/stub_sweep.py [--angles 55 70 90] [--ratios 0.3 0.45 0.6] [--lengths 1 1.5 2] [--work DIR]
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from data_synthetic.vessel_generator import stub_vessel, write_vessel  # noqa: E402
from vmesh.chain import FilterChain  # noqa: E402
from vmesh.context import Context  # noqa: E402


def run_one(folder: Path, angle: float, ratio: float, length: float) -> str:
    """The default chain (no files written) on one stub vessel; its table row."""
    m = write_vessel(stub_vessel(angle, ratio, length), folder)
    chain = FilterChain.load("default")
    chain.steps = [s for s in chain.steps if not s.filter.startswith("write")]
    ctx = Context()
    t0 = time.perf_counter()
    try:
        chain.run(surface=folder / m["files"]["surface"], skeleton=folder / m["files"]["centerline_vtp"], context=ctx)
        q = ctx.report.sections["quality"]["scaled_jacobian"]
        result = f"ok {q['min']:.3f} / {q['mean']:.3f}"
    except Exception as exc:  # a row per vessel, whatever fails
        result = f"FAIL {type(exc).__name__}: {str(exc)[:110]}"
    cut = [s["cap"] for s in ctx.report.sections.get("blocks", {}).get("cut_stubs", [])]
    filled = [h["diameter"] for h in ctx.report.sections.get("repair", {}).get("filled_holes", [])]
    holes = ", ".join(f"{d:.2f}" for d in filled) or "-"
    return f"| {angle:g} | {ratio:g} | {length:g} | {result} | {', '.join(cut) or '-'} | {holes} | {time.perf_counter() - t0:.1f} |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles", type=float, nargs="+", default=[55.0, 70.0, 90.0])
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.3, 0.45, 0.6])
    ap.add_argument("--lengths", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    ap.add_argument("--work", default=None, help="folder for the vessels (default: a temporary one)")
    args = ap.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="stub_sweep_"))
    print("| angle | ratio | length (stub radii past the wall) | result (SJ min / mean) | cut | holes filled (diameter) | s |")
    print("|---|---|---|---|---|---|---|")
    for a, r, L in itertools.product(args.angles, args.ratios, args.lengths):
        print(run_one(work / f"{a:g}_{r:g}_{L:g}", a, r, L), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
