"""The BraVa BG0002 whole-brain tree end to end: time per stage, peak memory and quality.

Issue 17 asks that the BraVa BG0002 tree (``brava_BG0002_surface.vtp``, 400,000 triangles,
with ``brava_BG0002.swc``, 2,541 nodes) mesh with the default chain in under 60 s on the
2-core machine, with 0 inverted elements and under 6 GB peak memory. Each variant (the SWC
``given``, and the skeleton ``extracted`` from the surface) runs in a child process bounded
by ``--timeout``; the child reports the seconds of every step it finished (and of the step
that failed), its CPU seconds and its peak resident memory (``resource.getrusage``), the
hexahedra, inverted elements and min / mean scaled Jacobian, and for the block builder the
assemblies it did and the rays it cast and reused (``blocks.info["work"]``).

A run that fails reports how far it got: the error line and the seconds per stage up to it.

Usage::

    python benchmarks/brava.py                         # given and extracted
    python benchmarks/brava.py --variants given --timeout 300

Writes ``benchmarks/results/brava.json`` and ``.md`` (``--name`` changes the stem).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402
from vmesh import realdata  # noqa: E402

SURFACE, CENTERLINE = "brava_BG0002_surface.vtp", "brava_BG0002.swc"
TARGET_S, TARGET_GB = 60.0, 6.0


def _count_step_cpu() -> dict:
    """Record the CPU seconds (all threads of this process) of every chain step, the failed
    one included, in the returned dict: on the shared machine wall seconds mostly measure the
    load, CPU seconds the work."""
    import vmesh.chain as chain_module

    cpu = {}
    run_step = chain_module._run_step

    def timed(ctx, number, step, *args, **kwargs):
        t = os.times()
        try:
            return run_step(ctx, number, step, *args, **kwargs)
        finally:
            u = os.times()
            cpu[step.filter] = cpu.get(step.filter, 0.0) + (u.user + u.system) - (t.user + t.system)

    chain_module._run_step = timed
    return cpu


def run_child(variant: str) -> dict:
    """One run in this process (the child): the row as :func:`_common.mesh_row` gives it,
    plus the failed step's seconds, CPU seconds per step and stage, the block builder's work
    and the peak memory."""
    surface = realdata.real_file(SURFACE)
    skeleton = realdata.real_file(CENTERLINE) if variant == "given" else None
    cpu = _count_step_cpu()
    row = C.mesh_row("brava_BG0002", surface, skeleton, exports=True, keep_context=True, label=variant)
    row["step_cpu_s"] = {k: round(v, 2) for k, v in cpu.items()}
    stage_cpu = {}
    for k, v in cpu.items():
        stage_cpu[C.STAGES.get(k, "export")] = stage_cpu.get(C.STAGES.get(k, "export"), 0.0) + v
    row["stage_cpu_s"] = {k: round(v, 2) for k, v in stage_cpu.items()}
    ctx = row.pop("_ctx", None)
    row.pop("_sj", None)
    if ctx is not None and ctx.blocks is not None:
        row["block_work"] = ctx.blocks.info.get("work")
    if row["status"] != "ok":
        # the failed step is not in the report: it took what the finished ones did not
        row.setdefault("stage_s", {})
        done = sum(row.get("step_s", {}).values())
        row["failed_step_s"] = round(max(0.0, row["wall_s"] - done), 3)
        ran = [k for k in cpu if k not in row.get("step_s", {})]
        row["failed_filter"] = ran[-1] if ran else None
    row["peak_rss_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)
    return row


def run_variant(variant: str, timeout: float) -> dict:
    """Run one variant in a child process with a time limit."""
    cmd = [sys.executable, __file__, "--child", variant]
    env = {**os.environ, "PYTHONPATH": str(C.ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=C.ROOT)
    except subprocess.TimeoutExpired:
        return {"run": variant, "status": "timeout", "error": f"over {timeout:.0f} s", "wall_s": round(time.perf_counter() - t0, 1)}
    lines = [line for line in p.stdout.splitlines() if line.startswith("{")]
    if p.returncode or not lines:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"run": variant, "status": "crashed", "error": f"exit {p.returncode}: {tail[0][:300]}",
                "wall_s": round(time.perf_counter() - t0, 1)}
    return json.loads(lines[-1])


def _gb(row: dict) -> float | None:
    return row.get("peak_rss_gb")


def tabulate(rows: list[dict]) -> str:
    stages = list(C.STAGE_ORDER)
    head = ["run", "status", "wall s", "CPU s"] + [f"{s} s wall / CPU" for s in stages] + ["peak GB", "hexahedra", "inverted", "SJ min",
                                                                                              "SJ mean", "assemblies", "rays cast / reused"]
    lines = []
    for r in rows:
        st, cpu = r.get("stage_s", {}), r.get("stage_cpu_s", {})
        if r.get("failed_filter"):  # the report has no seconds of the failed step: the wall clock had them
            stage = C.STAGES.get(r["failed_filter"], "export")
            st = {**st, stage: st.get(stage, 0.0) + (r.get("failed_step_s") or 0.0)}
        work = r.get("block_work") or {}
        cells = [r["run"], r["status"], C.fmt(r.get("wall_s"), ".1f"), C.fmt(r.get("cpu_s"), ".1f")]
        cells += [f"{C.fmt(st.get(s), '.1f')} / {C.fmt(cpu.get(s), '.1f')}" for s in stages]
        cells += [C.fmt(_gb(r), ".2f"), C.fmt(r.get("elements")), C.fmt(r.get("invalid")), C.fmt(r.get("sj_min"), ".3f"),
                  C.fmt(r.get("sj_mean"), ".3f"), C.fmt(work.get("assemblies")),
                  f"{C.fmt(work.get('rays_cast'))} / {C.fmt(work.get('rays_reused'))}" if work else "-"]
        lines.append(cells)
    md = C.table(head, lines)
    notes = []
    for r in rows:
        if r["status"] != "ok":
            note = f"- {r['run']}: {r.get('error', '')}"
            if r.get("failed_step_s") is not None:
                note += f" ({r.get('failed_step')}: the failing step took {r['failed_step_s']:.1f} s)"
            notes.append(note)
        else:
            ok = r.get("wall_s", 1e9) < TARGET_S and (_gb(r) or 1e9) < TARGET_GB and r.get("invalid", 1) == 0
            notes.append(f"- {r['run']}: {'meets' if ok else 'misses'} the target (< {TARGET_S:.0f} s, < {TARGET_GB:.0f} GB, 0 inverted)")
    text = "\n".join(notes)
    print(text)
    return md + "\n\n" + text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="+", default=["given", "extracted"], choices=["given", "extracted"])
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per run (default 600)")
    ap.add_argument("--name", default="brava")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(C.clean_rows([run_child(args.child)])[0], default=str), flush=True)
        return 0
    if realdata.real_file(SURFACE) is None or realdata.real_file(CENTERLINE) is None:
        print(f"skipped: {realdata.missing_reason()} ({SURFACE}, {CENTERLINE})")
        return 0
    print(f"BraVa BG0002, default chain; {C.load_line()}", flush=True)
    rows = []
    for variant in args.variants:
        rows.append(run_variant(variant, args.timeout))
        print(f"  {variant}: {rows[-1]['status']} in {rows[-1].get('wall_s')} s", flush=True)
    md = tabulate(rows)
    C.RESULTS.mkdir(parents=True, exist_ok=True)
    C.write_text_atomic(C.RESULTS / f"{args.name}.json", json.dumps({"load": C.load_line(), "rows": rows}, indent=1, default=str))
    C.write_text_atomic(C.RESULTS / f"{args.name}.md", f"# BraVa BG0002 end to end\n\n{C.load_line()}\n\n{md}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
