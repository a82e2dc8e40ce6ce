"""Cost against mesh size: the default chain over ``mesh_transfinite.refinement`` 1-4 on vessel trees.

Each run is a whole ``vmesh run default`` process (imports and file writing count) on one
tree at one refinement, with a time limit; when a tree's run fails or runs out of time, its
higher refinements are skipped (they would only take longer). Per tree the table lists the
hexahedra, the process wall time and the seconds of each stage (from the run's
report.json), and a least-squares line ``seconds = fixed + slope x million hexahedra`` over
its refinements, end to end and per stage: the slope is the cost per million hexahedra
beyond the fixed costs (target: <= 2 s per million end to end).

Trees: the ICA (``ica_swc_surface.vtp`` + ``ica_centerline.swc``), the synthetic cerebral
tree (``data_synthetic/cerebral_tree``) and BraVa BG0002 (``brava_BG0002_surface.vtp`` +
``brava_BG0002.swc``), each where found (real data: ``$VMESH_REAL_DATA`` or
``../shared/data/real``; a missing one is skipped with the reason).

The machine is shared: the load average is printed with the table; runs of one tree are
measured back to back.

Usage::

    python benchmarks/scaling.py                               # all trees, refinement 1-4
    python benchmarks/scaling.py --trees ica cerebral_tree --refinements 1 2 3 --timeout 300

Writes ``benchmarks/results/scaling.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402

ROOT = C.ROOT
STAGES = ("pre", "sdf", "skel", "blocks", "hex", "quality", "export")
TARGET_S_PER_MILLION = 2.0


def trees() -> dict[str, tuple[Path | None, Path | None, str]]:
    """``{name: (surface, centerline, reason when absent)}``."""
    from vmesh import realdata

    out = {}
    for name, surface, centerline in (("ica", "ica_swc_surface.vtp", "ica_centerline.swc"),
                                      ("brava_BG0002", "brava_BG0002_surface.vtp", "brava_BG0002.swc")):
        s, c = realdata.real_file(surface), realdata.real_file(centerline)
        out[name] = (s, c, "" if s and c else f"{realdata.missing_reason()} ({surface}, {centerline})")
    s, c = C.SYNTHETIC / "cerebral_tree" / "surface.ply", C.SYNTHETIC / "cerebral_tree" / "skeleton.json"
    out["cerebral_tree"] = (s, c, "" if s.exists() and c.exists() else "data_synthetic/cerebral_tree not generated")
    return out


def run_once(tree: str, surface: Path, centerline: Path, refinement: int, out: Path, timeout: float) -> dict:
    cmd = [sys.executable, "-m", "vmesh", "run", "default", "-i", str(surface), "-s", str(centerline), "-o", str(out), "-q",
           "--set", f"mesh_transfinite.refinement={refinement}", "--set", "compute_quality.fail_on_invalid=false"]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    row = {"tree": tree, "refinement": refinement, "status": "ok"}
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {**row, "status": "timeout", "error": f"over {timeout:.0f} s", "wall_s": round(time.perf_counter() - t0, 1)}
    row["wall_s"] = round(time.perf_counter() - t0, 3)
    if p.returncode:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
        return {**row, "status": "failed", "error": f"exit {p.returncode}: {tail[0][:300]}"}
    report = json.loads((out / "report.json").read_text())
    stages = dict.fromkeys(STAGES, 0.0)
    for name, seconds in report["timings"].items():
        stages[C.STAGES.get(name, "export")] += seconds
    q = report.get("quality", {}).get("scaled_jacobian", {})
    row.update(hexahedra=int(report["counts"]["elements"]), nodes=int(report["counts"]["nodes"]),
               chain_s=round(report["total_s"], 3), start_s=round(row["wall_s"] - report["total_s"], 3),
               stage_s={k: round(v, 3) for k, v in stages.items()},
               step_s={k: round(v, 3) for k, v in report["timings"].items()},
               sj_min=q.get("min"), sj_mean=q.get("mean"), invalid=q.get("n_invalid"))
    if isinstance(report.get("untangle"), dict):
        row["untangled_nodes"] = report["untangle"].get("moved")
    return row


def fit(rows: list[dict], key) -> dict | None:
    """Least-squares ``seconds = fixed + slope * Mhex`` over the rows (None with < 2 sizes)."""
    pts = [(r["hexahedra"] / 1e6, key(r)) for r in rows if r["status"] == "ok"]
    if len({x for x, _ in pts}) < 2:
        return None
    x, y = np.array(pts).T
    slope, fixed = np.polyfit(x, y, 1)
    return {"fixed_s": round(float(fixed), 3), "s_per_million": round(float(slope), 3)}


def main(argv=None):
    all_trees = trees()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trees", nargs="+", default=list(all_trees), choices=list(all_trees))
    ap.add_argument("--refinements", nargs="+", type=int, default=[1, 2, 3, 4])
    ap.add_argument("--timeout", type=float, default=600, help="seconds per run; a tree stops at its first failure or timeout")
    ap.add_argument("--no-write", action="store_true", help="print only, leave benchmarks/results alone")
    args = ap.parse_args(argv)

    load_before = C.load_line()
    print(load_before, flush=True)
    rows, fits = [], {}
    with tempfile.TemporaryDirectory(prefix="vmesh-scaling-") as tmp:
        for tree in args.trees:
            surface, centerline, reason = all_trees[tree]
            if reason:
                print(f"{tree}: skipped: {reason}", flush=True)
                continue
            tree_rows = []
            for r in sorted(args.refinements):
                print(f"{tree} refinement {r} ...", flush=True)
                row = run_once(tree, surface, centerline, r, Path(tmp) / f"{tree}_{r}", args.timeout)
                tree_rows.append(row)
                if row["status"] != "ok":
                    print(f"  {row['status']}: {row['error']}; higher refinements of {tree} skipped", flush=True)
                    break
                print(f"  {row['hexahedra']:,} hexahedra in {row['wall_s']:.1f} s", flush=True)
            rows += tree_rows
            f = {"wall": fit(tree_rows, lambda r: r["wall_s"])}
            for s in STAGES:
                f[s] = fit(tree_rows, lambda r, s=s: r["stage_s"][s])
            fits[tree] = f
            if not args.no_write:  # after every tree: a long run stopped later keeps what it measured
                write(rows, fits, load_before, quiet=True)
    if not args.no_write:
        write(rows, fits, load_before)
    else:
        report(rows, fits, load_before)
    return 0


def write(rows: list[dict], fits: dict, load_before: str, quiet: bool = False) -> None:
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
        md = report(rows, fits, load_before)
        header = ("# Cost against mesh size\n\nWritten by `python benchmarks/scaling.py`: whole `vmesh run default` processes "
                  "over `mesh_transfinite.refinement`, seconds per stage from each run's report.json, and the least-squares "
                  "cost per million hexahedra beyond the fixed costs. Shared 2-core machine: times are noisy.")
        js, mdp = C.write_results("scaling", rows, md, header, extra={"fits": fits, "target_s_per_million": TARGET_S_PER_MILLION})
        print(f"\nwritten {js.relative_to(ROOT)}, {mdp.name}")


def report(rows: list[dict], fits: dict, load_before: str) -> str:
    head = ["tree", "ref", "hexahedra", "wall s", "start s", *[f"{s} s" for s in STAGES], "SJ min", "invalid", "untangled"]
    lines = []
    for r in rows:
        if r["status"] != "ok":  # the reason goes below the table
            lines.append([r["tree"], str(r["refinement"]), r["status"], C.fmt(r.get("wall_s")), *[""] * (len(STAGES) + 4)])
            continue
        lines.append([r["tree"], str(r["refinement"]), f"{r['hexahedra']:,}", f"{r['wall_s']:.2f}", f"{r['start_s']:.2f}",
                      *[f"{r['stage_s'][s]:.2f}" for s in STAGES], C.fmt(r.get("sj_min"), ".3f"), C.fmt(r.get("invalid")),
                      C.fmt(r.get("untangled_nodes"))])
    print()
    md = C.table(head, lines)
    reasons = [f"{r['tree']} refinement {r['refinement']}: {r['status']}: {r['error']}" for r in rows if r["status"] != "ok"]
    if reasons:
        print("\n" + "\n".join(reasons))
        md += "\n\n" + "\n".join(f"- {line}" for line in reasons)
    fit_lines = []
    for tree, f in fits.items():
        if f["wall"] is None:
            fit_lines.append([tree, "fewer than 2 sizes", "", ""])
            continue
        verdict = "meets" if f["wall"]["s_per_million"] <= TARGET_S_PER_MILLION else "misses"
        per_stage = ", ".join(f"{s} {f[s]['s_per_million']:.2f}" for s in STAGES if f[s] is not None)
        fit_lines.append([tree, f"{f['wall']['fixed_s']:.2f}", f"{f['wall']['s_per_million']:.2f} ({verdict} <= {TARGET_S_PER_MILLION:g})", per_stage])
    print()
    md += "\n\nLeast-squares fit `seconds = fixed + slope x million hexahedra` per tree:\n\n"
    md += C.table(["tree", "fixed s", "s per million hex (end to end)", "s per million hex by stage"], fit_lines)
    md += f"\n\n{load_before} before the runs, {C.load_line()} after."
    print(f"\n{C.load_line()}")
    return md


if __name__ == "__main__":
    sys.exit(main())
