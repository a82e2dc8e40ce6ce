"""Robustness of the default chain: success rate over generated vessels and every real surface.

Cases
-----
* ``generated``: ``--n`` vessels of :mod:`data_synthetic.vessel_generator` (``--seed``,
  ``--preset clean|rough|mixed``), each run with its true skeleton (``given``: the VMTK-style
  centerline for even vessel numbers, the SWC for odd ones, or skeleton.json when the vessel
  has a loop) and with an extracted one.
* ``real``: every surface of :data:`vmesh.realdata.REAL_CORPUS`, with its centerline where the
  data set has one (``given``) and with an extracted skeleton (``extracted``).

Every run is one task on a local Dask cluster (``--workers`` single-threaded processes, the
cluster of ``vmesh batch``), and inside it a child process bounded by ``--timeout`` seconds,
so that no case can hang the benchmark. A run is a **success** when the chain finished with
0 invalid elements, min scaled Jacobian >= 0.3, mean >= 0.9 and, where ``report.json`` has a
``coverage`` section (the ``check_coverage`` filter), the coverage passed. Failures are grouped
by stage and by cause (the error with numbers and names normalised away); each failure keeps
pictures of what was reached (surface, skeleton, blocks, or the mesh) in ``WORK/<case>/``.

Usage::

    python benchmarks/robustness.py                              # 200 generated + real (hours)
    python benchmarks/robustness.py --real-only --timeout 300
    python benchmarks/robustness.py --generated-only --n 24 --preset rough --seed 3
    python benchmarks/robustness.py --cases carotid:given g0003:extracted
    python benchmarks/robustness.py --refinement 2               # the coverage criterion
    python benchmarks/robustness.py --set build_block_structure.saddle_split=0.5   # an option on every run

Writes ``benchmarks/results/robustness.json`` and ``.md`` (``--name`` changes the stem) and
per-case folders under ``--work`` (default ``out/robustness``). Each row of the JSON carries
``command``: the ``vmesh run`` line that reproduces it by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402
from vmesh import realdata  # noqa: E402

#: Success thresholds of issue 17.
SJ_MIN, SJ_MEAN, COVERAGE_FAR_SHARE = 0.3, 0.9, 0.01


# ---------------------------------------------------------------------------
# cases
# ---------------------------------------------------------------------------
def real_tasks() -> list[dict]:
    """Two runs (given centerline, extracted skeleton) per real surface; one when it has none."""
    if realdata.real_data_dir() is None:
        print(f"skipped real cases: {realdata.missing_reason()}")
        return []
    out = []
    for key, surface, centerline, case in realdata.real_corpus():
        base = {"group": "real", "case": key, "surface": str(surface), "features": [f"units_{case.units}"]
                + (["components"] if case.components > 1 else []) + (["volume_mesh"] if case.volume_mesh else [])
                + (["open_ends"] if case.open_ends else ["closed"])}
        if centerline is not None:
            out.append({**base, "variant": "given", "skeleton": str(centerline)})
        out.append({**base, "variant": "extracted", "skeleton": None})
    return out


def generated_tasks(work: Path, n: int, seed: int, preset: str, client) -> list[dict]:
    """Generate ``n`` vessels (on the Dask workers) and two runs per vessel."""
    from data_synthetic.vessel_generator import generate_one

    folder = work / f"generated_{preset}_s{seed}"
    futures = [client.submit(generate_one, folder, i, seed, preset, pure=False) for i in range(n)]
    out = []
    for i, f in enumerate(futures):
        try:
            m = f.result()
        except Exception as exc:  # a generator failure is a row, not a crash
            out.append({"group": "generated", "case": f"g{i:04d}", "variant": "-", "surface": "", "skeleton": None,
                        "features": [], "generator_error": f"{type(exc).__name__}: {exc}"})
            continue
        d = Path(m["folder"])
        base = {"group": "generated", "case": d.name, "surface": str(d / m["files"]["surface"]),
                "features": sorted(k for k, v in m["features"].items() if v)
                + [f"preset_{m['preset']}", f"ends_{m['end_style']}", f"units_{m['units']}"]}
        # an SWC cannot hold a loop's closing segment: loops get the JSON skeleton instead
        skel = m["files"]["centerline_vtp"] if i % 2 == 0 else m["files"]["skeleton_json" if m["features"].get("loop") else "swc"]
        out += [{**base, "variant": "given", "skeleton": str(d / skel)}, {**base, "variant": "extracted", "skeleton": None}]
    return out


# ---------------------------------------------------------------------------
# one run (child process)
# ---------------------------------------------------------------------------
def command_line(task: dict, overrides: dict) -> str:
    """The ``vmesh run`` command that reproduces a task by hand."""
    cmd = f"vmesh run default -i {task['surface']}"
    if task.get("skeleton"):
        cmd += f" -s {task['skeleton']}"
    cmd += "".join(f" --set {k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in overrides.items())
    return cmd + f" -o out/{task['case']}_{task['variant']}"


def coverage_of(report: dict) -> dict | None:
    """The coverage section of a run's report (``check_coverage``), when it has one."""
    sections = report.get("sections", report)
    cov = sections.get("coverage") if isinstance(sections, dict) else None
    return cov if isinstance(cov, dict) else None


def coverage_passed(cov: dict | None) -> bool | None:
    """``None`` without a coverage section, else whether it passed (its own verdict when it has one)."""
    if cov is None:
        return None
    for key in ("passed", "ok", "success"):
        if isinstance(cov.get(key), bool):
            return cov[key]
    share = next((cov[k] for k in cov if ("share" in k or "fraction" in k) and isinstance(cov[k], (int, float))), None)
    return None if share is None else share <= COVERAGE_FAR_SHARE


def judge(row: dict) -> list[str]:
    """Why a run is not a success (empty: success): the quality targets, then coverage."""
    miss = C.check_targets(row, SJ_MIN, SJ_MEAN, missing_passes=False)
    if row["status"] == "ok" and coverage_passed(row.get("coverage")) is False:
        miss.append("coverage failed")
    return miss


def render_reached(ctx, folder: Path) -> list[str]:
    """Pictures of what a run reached: the mesh (``vmesh render``'s pictures) or else the
    surface, skeleton and blocks; returns the file names written."""
    from vmesh.render import render_pictures

    folder.mkdir(parents=True, exist_ok=True)
    if ctx is None:
        return []
    surface = ctx.surface if getattr(ctx, "surface", None) is not None else None
    if getattr(ctx, "mesh", None) is not None:
        return [p.name for p in render_pictures(folder, ctx.mesh, surface, ctx.skeleton, None).values()]
    done = []
    if ctx.skeleton is not None:
        from vmesh.filters.skeleton_filters import render_skeleton_png

        render_skeleton_png(folder / "skeleton.png", ctx.skeleton, surface, (1000, 750), 0.2, title="reached: skeleton")
        done.append("skeleton.png")
        from vmesh.io.skeleton import write_skeleton

        write_skeleton(folder / "skeleton.json", ctx.skeleton)
    if surface is not None:
        from vmesh.io.surface import write_surface

        write_surface(folder / "surface.vtp", surface)
        done.append("surface.vtp")
    blocks = getattr(ctx, "blocks", None)
    if blocks is not None and hasattr(blocks, "to_pyvista"):
        try:
            blocks.to_pyvista().save(str(folder / "blocks.vtu"))
            done.append("blocks.vtu")
        except Exception:  # pictures are a help, never a reason to lose the row
            pass
    return done


def run_one(task: dict) -> dict:
    """Run one task in this process (the child): mesh, judge, render a failure, write result.json."""
    import faulthandler

    folder = Path(task["dir"])
    folder.mkdir(parents=True, exist_ok=True)
    # a stack dump just before the parent kills a run names where it was stuck
    faulthandler.dump_traceback_later(max(1.0, task["timeout"] - 3), exit=False)
    row = C.mesh_row(task["case"], task["surface"], task.get("skeleton"), overrides=task["overrides"],
                     exports=False, keep_context=True, label=task["variant"])
    ctx = row.pop("_ctx", None)
    row.pop("_sj", None)
    if ctx is not None:
        row["coverage"] = coverage_of(ctx.report.to_dict())
    row["misses"] = judge(row)
    row["success"] = not row["misses"]
    save = lambda: (folder / "result.json").write_text(json.dumps(C.clean_rows([row])[0], indent=1, default=C._json_default))
    save()  # before the pictures: a render that runs out of time must not lose the row
    if not row["success"]:
        try:
            row["pictures"] = render_reached(ctx, folder / "reached")
        except Exception as exc:
            row["pictures_error"] = f"{type(exc).__name__}: {exc}"[:200]
        save()
    return row


def run_task(task: dict) -> dict:
    """Run one task in a child process bounded by ``task['timeout']`` (runs on a Dask worker)."""
    folder = Path(task["dir"])
    folder.mkdir(parents=True, exist_ok=True)
    result = folder / "result.json"
    result.unlink(missing_ok=True)
    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(C.ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with open(folder / "log.txt", "w") as log:
        proc = subprocess.Popen([sys.executable, __file__, "--one", json.dumps(task)], stdout=log, stderr=subprocess.STDOUT,
                                env=env, start_new_session=True)
        try:
            proc.wait(timeout=task["timeout"])
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            if result.is_file():  # the run ended; its pictures did not
                return {**_base(task), **json.loads(result.read_text()), "pictures_error": "rendering ran out of time"}
            stage = _last_step(folder / "log.txt")
            return {**_base(task), "status": "failed", "error": f"timeout after {task['timeout']} s" + (f" in {stage}" if stage else ""),
                    "wall_s": round(time.perf_counter() - t0, 1), "success": False, "misses": ["timeout"]}
    if result.is_file():
        return {**_base(task), **json.loads(result.read_text())}
    tail = (folder / "log.txt").read_text(errors="replace").strip().splitlines()[-1:] or ["no output"]
    return {**_base(task), "status": "failed", "error": f"child process died (exit {proc.returncode}): {tail[0][:200]}",
            "wall_s": round(time.perf_counter() - t0, 1), "success": False, "misses": ["crash"]}


def _base(task: dict) -> dict:
    return {k: task[k] for k in ("group", "case", "variant", "features", "command")}


def _last_step(log: Path) -> str:
    """Where a timed-out child was, from its stack dump: ``filter (innermost vmesh function)``
    of the thread that runs the chain."""
    text = log.read_text(errors="replace") if log.is_file() else ""
    block = next((b for b in text.split("\n\n") if "vmesh/chain.py" in b), "")
    frames = re.findall(r'vmesh/([\w/]+)\.py", line \d+ in (\w+)', block)
    filt = [f for m, f in frames if m.startswith("filters/")]
    if not frames:
        return ""
    inner = f"{frames[0][0].replace('/', '.')}.{frames[0][1]}"
    return f"{filt[-1]} ({inner})" if filt else inner


# ---------------------------------------------------------------------------
# causes and tables
# ---------------------------------------------------------------------------
_STEP = re.compile(r"step \d+ '([a-z_]+)'")


def stage_and_cause(row: dict) -> tuple[str, str]:
    """The stage a run failed in and its error normalised into a cause (numbers, paths,
    quoted names replaced) so that equal causes group together."""
    if row.get("success"):
        return "", ""
    err = row.get("error") or "; ".join(row.get("misses", []))
    m = _STEP.search(err)
    stage = m.group(1) if m else (row.get("failed_step") or ("quality" if row["status"] == "ok" else "input"))
    if err.startswith("timeout"):
        stage = err.split(" in ")[-1].split(" (")[0] if " in " in err else "timeout"
    text = _STEP.sub("", err)
    text = re.sub(r"^\w+Error: ", "", text.strip(" :")).strip(" :")
    text = re.sub(r"\S*/\S+", "PATH", text)
    text = re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "N", text)
    text = re.sub(r"\(N[^)]*\)", "", text)
    cause = " ".join(text.split(". ")[0].split())[:110]
    if row["status"] == "ok":
        cause = "; ".join(re.sub(r"-?\d+(\.\d+)?", "N", x) for x in row.get("misses", []))
    return stage, cause


def summarise(rows: list[dict]) -> tuple[str, dict]:
    """Markdown tables and the numbers behind them."""
    md, stats = [], {}
    for group in ("real", "generated"):
        g = [r for r in rows if r["group"] == group]
        if not g:
            continue
        ok = sum(bool(r.get("success")) for r in g)
        stats[group] = {"runs": len(g), "success": ok, "rate": round(ok / len(g), 4)}
        md.append(f"**{group}**: {ok} / {len(g)} runs succeed ({100 * ok / len(g):.1f} %)"
                  + "".join(f"; {v}: {sum(bool(r.get('success')) for r in g if r['variant'] == v)} / {sum(r['variant'] == v for r in g)}"
                            for v in ("given", "extracted")) + "\n")
    causes = Counter()
    for r in rows:
        if not r.get("success"):
            causes[(r["group"],) + stage_and_cause(r)] += 1
    md.append("\n### Failures by stage and cause\n")
    md.append(C.table(["group", "stage", "cause", "runs"], [[g, s, c.replace("|", "/"), str(n)] for (g, s, c), n in causes.most_common()]))
    stats["causes"] = [{"group": g, "stage": s, "cause": c, "runs": n} for (g, s, c), n in causes.most_common()]
    feats = defaultdict(lambda: [0, 0])
    for r in rows:
        if r["group"] == "generated":
            own = [f for f in r.get("features", []) if not f.startswith(("preset_", "ends_", "units_"))]
            for f in r.get("features", []) + ([] if own else ["(no feature)"]):
                feats[f][0] += 1
                feats[f][1] += bool(r.get("success"))
    if feats:
        md.append("\n### Generated vessels by feature\n")
        md.append(C.table(["feature", "runs", "success", "rate %"], [[f, str(n), str(s), f"{100 * s / n:.0f}"] for f, (n, s) in sorted(feats.items())]))
    ok_rows = [r for r in rows if r["status"] == "ok" and r.get("sj_min") is not None]
    if ok_rows:
        import numpy as np

        mins, means = np.array([r["sj_min"] for r in ok_rows]), np.array([r["sj_mean"] for r in ok_rows])
        walls = np.array([r.get("wall_s", np.nan) for r in rows], float)
        stats["sj_min_quantiles"] = np.round(np.quantile(mins, [0, 0.1, 0.5, 0.9, 1]), 3).tolist()
        stats["sj_mean_quantiles"] = np.round(np.quantile(means, [0, 0.1, 0.5, 0.9, 1]), 3).tolist()
        stats["wall_s_quantiles"] = np.round(np.nanquantile(walls, [0, 0.5, 0.9, 1]), 1).tolist()
        md.append("\n### Distributions (finished runs)\n")
        md.append(C.table(["quantity", "min", "p10", "median", "p90", "max"],
                          [["SJ min"] + [f"{v:.3f}" for v in stats["sj_min_quantiles"]],
                           ["SJ mean"] + [f"{v:.3f}" for v in stats["sj_mean_quantiles"]],
                           ["wall s (all runs)", *[f"{v:.1f}" for v in stats["wall_s_quantiles"][:1]], "-",
                            *[f"{v:.1f}" for v in stats["wall_s_quantiles"][1:]]]]))
    md.append("\n### Every run\n")
    lines = []
    for r in rows:
        stage, cause = stage_and_cause(r)
        lines.append([r["group"], r["case"], r["variant"], "ok" if r.get("success") else "FAIL", stage,
                      C.fmt(r.get("sj_min"), ".3f"), C.fmt(r.get("sj_mean"), ".3f"), C.fmt(r.get("invalid")),
                      C.fmt(r.get("wall_s"), ".1f"), (r.get("error") or "; ".join(r.get("misses", [])))[:150].replace("|", "/")])
    md.append(C.table(["group", "case", "variant", "result", "stage", "SJ min", "SJ mean", "invalid", "wall s", "error / miss"], lines))
    return "\n".join(md), stats


# ---------------------------------------------------------------------------
def merge(paths: list[Path], name: str) -> int:
    """Tabulate the rows of earlier result files as one benchmark (``--merge``)."""
    rows, runs = [], []
    for p in paths:
        d = json.loads(p.read_text())
        rows += d["rows"]
        runs.append(f"`{p.name}` ({d.get('when', '?')}, source `{d.get('vmesh_source_sha1', '?')}`)")
    rows.sort(key=lambda r: (r["group"] != "real", r["case"], r["variant"]))
    md, stats = summarise(rows)
    print(md)
    header = (f"# robustness\n\nMerged from {', '.join(runs)} by `python benchmarks/robustness.py --merge ...` (shared "
              f"machine: times are noisy). Success: 0 invalid elements, min SJ ≥ {SJ_MIN}, mean ≥ {SJ_MEAN}, coverage passed "
              "where reported.\n")
    js, mdp = C.write_results(name, rows, md, header, extra={"stats": stats, "merged_from": [str(p) for p in paths]})
    print(f"\nwritten {js.relative_to(C.ROOT)}, {mdp.name}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200, help="generated vessels (default 200); every real surface runs too (BraVa alone takes minutes) unless --generated-only")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated vessels (default 0)")
    ap.add_argument("--preset", default="mixed", choices=["clean", "rough", "mixed"])
    ap.add_argument("--real-only", action="store_true", help="only the real surfaces (../shared/data/real or $VMESH_REAL_DATA)")
    ap.add_argument("--generated-only", action="store_true", help="only the generated vessels (a quick try: --n 2 --generated-only --name try)")
    ap.add_argument("--cases", nargs="+", help="case names, or case:variant (e.g. carotid:given g0003:extracted)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per run (default 300)")
    ap.add_argument("--workers", type=int, default=max(1, min(2, os.cpu_count() or 1)), help="runs at a time (default: 2, or 1 on one core)")
    ap.add_argument("--refinement", type=int, help="mesh_transfinite.refinement (the coverage criterion is judged at 2)")
    ap.add_argument("--set", action="append", default=[], metavar="FILTER.PARAM=VALUE", dest="sets",
                    help="a parameter of the default chain for every run, as `vmesh run --set` (repeatable), "
                         "e.g. build_block_structure.saddle_split=0.5")
    ap.add_argument("--work", type=Path, default=C.ROOT / "out" / "robustness", help="per-case folders")
    ap.add_argument("--name", default="robustness", help="writes benchmarks/results/NAME.{json,md} (default robustness: the recorded results, which a trial run replaces)")
    ap.add_argument("--merge", nargs="+", type=Path, metavar="JSON",
                    help="no runs: tabulate the rows of earlier result files together (e.g. a real and a generated run)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        run_one(json.loads(args.one))
        return 0
    if args.merge:
        return merge(args.merge, args.name)
    from distributed import Client

    from vmesh.batch import _local_cluster

    overrides = {**C.BENCH_OVERRIDES}
    if args.refinement is not None:
        overrides["mesh_transfinite.refinement"] = args.refinement
    from vmesh.cli import parse_overrides
    from vmesh.commands.batch import check_overrides

    try:  # as `vmesh batch --set` parses and checks them: a typo fails here, not in every run
        sets = parse_overrides(args.sets)
        check_overrides("default", sets)
    except Exception as exc:
        ap.error(str(exc))
    overrides.update(sets)
    t0 = time.perf_counter()
    cluster = _local_cluster(args.workers)
    client = Client(cluster)
    try:
        tasks = [] if args.generated_only else real_tasks()
        if not args.real_only and args.n > 0:
            print(f"generating {args.n} vessels (preset {args.preset}, seed {args.seed}) ...", flush=True)
            tasks += generated_tasks(args.work, args.n, args.seed, args.preset, client)
        if args.cases:
            want = set(args.cases)
            tasks = [t for t in tasks if t["case"] in want or f"{t['case']}:{t['variant']}" in want]
        rows = [{**t, "status": "failed", "error": t["generator_error"], "success": False, "misses": ["generator"]}
                for t in tasks if "generator_error" in t]
        tasks = [t for t in tasks if "generator_error" not in t]
        for t in tasks:
            t.update(overrides=overrides, timeout=args.timeout, dir=str(args.work / "runs" / f"{t['case']}_{t['variant']}"),
                     command=command_line(t, overrides))
        print(f"{len(tasks)} runs on {args.workers} worker(s), timeout {args.timeout:.0f} s; {C.load_line()}", flush=True)
        from distributed import as_completed

        futures = {client.submit(run_task, t, pure=False): t for t in tasks}
        for k, f in enumerate(as_completed(futures), 1):
            t = futures[f]
            try:
                r = f.result()
            except Exception as exc:  # a lost worker is a failed row
                r = {**_base(t), "status": "failed", "error": f"{type(exc).__name__}: {exc}", "success": False, "misses": ["worker"]}
            rows.append(r)
            tag = "ok  " if r.get("success") else "FAIL"
            print(f"[{k}/{len(tasks)}] {tag} {r['case']}:{r['variant']} {C.fmt(r.get('wall_s'), '.1f')} s "
                  f"SJ {C.fmt(r.get('sj_min'), '.3f')}/{C.fmt(r.get('sj_mean'), '.3f')} {(r.get('error') or '; '.join(r.get('misses', [])))[:160]}", flush=True)
    finally:
        client.close()
        cluster.close()
    rows.sort(key=lambda r: (r["group"] != "real", r["case"], r["variant"]))
    md, stats = summarise(rows)
    print("\n" + md)
    header = (f"# robustness\n\n`python benchmarks/robustness.py {' '.join(argv if argv is not None else sys.argv[1:])}` — "
              f"{time.strftime('%Y-%m-%d %H:%M')}, {C.load_line()}, {time.perf_counter() - t0:.0f} s in all (shared machine: times "
              f"are noisy). Success: 0 invalid elements, min SJ ≥ {SJ_MIN}, mean ≥ {SJ_MEAN}, coverage passed where reported.\n")
    js, mdp = C.write_results(args.name, rows, md, header, extra={"stats": stats, "overrides": overrides})
    print(f"\nwritten {js.relative_to(C.ROOT)}, {mdp.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
