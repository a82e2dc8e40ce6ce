"""CPU and wall seconds per step of one in-process ``vmesh run`` (a loaded machine's wall
clock says little; CPU seconds per step compare back to back).

Usage::

    python benchmarks/stage_cpu.py run default -q -i SURFACE [-s CENTERLINE] -o OUT [--set ...]
    python benchmarks/stage_cpu.py --ica OUT     # the ICA at vascularmd's resolution

Prints a table: the import of ``vmesh.cli``, every step (``time.process_time``, all threads,
and ``time.perf_counter``), the whole run, and the load average.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ICA = ["--set", "mesh_transfinite.elements_around=6", "--set", "mesh_transfinite.elements_ring=4", "--set", "mesh_transfinite.elements_layer=4",
       "--set", "mesh_transfinite.element_length=0.25", "--set", "compute_quality.fail_on_invalid=false"]


def ica_args(out: str) -> list[str]:
    """``vmesh run`` arguments of the ICA at vascularmd's resolution (docs/speed.md)."""
    real = Path(os.environ.get("VMESH_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
    return ["run", "default", "-q", "-i", str(real / "ica_swc_surface.vtp"), "-s", str(real / "ica_centerline.swc"), "-o", out, *ICA]


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):  # its own usage, not vmesh's
        print(__doc__)
        return 0
    c, w = time.process_time(), time.perf_counter()
    import vmesh.chain as chain
    from vmesh.cli import main as vmesh_main

    rows = [("imports (vmesh.cli)", time.process_time() - c, time.perf_counter() - w)]
    original = chain._run_step

    def timed(ctx, number, step, *args):
        c, w = time.process_time(), time.perf_counter()
        try:
            return original(ctx, number, step, *args)
        finally:
            rows.append((step.filter, time.process_time() - c, time.perf_counter() - w))

    chain._run_step = timed
    args = ica_args(argv[1]) if argv[:1] == ["--ica"] else argv
    c, w = time.process_time(), time.perf_counter()
    try:
        rc = vmesh_main(args)
    finally:
        chain._run_step = original
    rows.append(("run (all steps)", time.process_time() - c, time.perf_counter() - w))
    print(f"load average {os.getloadavg()[0]:.1f}\n\n| stage | CPU s | wall s |\n|---|---|---|")
    for name, cpu, wall in rows:
        print(f"| {name} | {cpu:.2f} | {wall:.2f} |")
    return rc or 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
