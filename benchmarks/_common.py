"""Shared helpers of the meshing benchmarks (mesh_cases, paper_cases, all_real, vs_unstructured).

One call of :func:`mesh_row` runs the default chain on one surface and returns a flat row
(counts, seconds per stage, quality, boundary distance) or, when anything fails, a row with
``status = "failed"`` and the reason; a benchmark never stops on one bad case.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vmesh import realdata  # noqa: E402
from vmesh.chain import FilterChain  # noqa: E402
from vmesh.io.atomic import write_text_atomic  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
SYNTHETIC = ROOT / "data_synthetic"

#: Filters grouped into the stages reported in the tables.
STAGES = {
    "repair_surface": "pre",
    "cap_open_ends": "pre",
    "detect_caps": "pre",
    "decimate_surface": "pre",
    "smooth_loop": "pre",
    "build_sdf": "sdf",
    "extract_skeleton": "skel",
    "load_skeleton": "skel",
    "estimate_radii": "skel",
    "clean_skeleton": "skel",
    "resample_skeleton": "skel",
    "build_block_structure": "blocks",
    "mesh_transfinite": "hex",
    "label_elements": "quality",
    "compute_quality": "quality",
}
STAGE_ORDER = ("pre", "sdf", "skel", "blocks", "hex", "quality", "export")

#: Scaled Jacobian histogram bins kept in the JSON rows (-1..1, so invalid elements show).
SJ_BINS = np.linspace(-1.0, 1.0, 81)

#: Overrides of every benchmark run: a row with invalid elements is reported, not raised.
BENCH_OVERRIDES = {"compute_quality.fail_on_invalid": False}


def load_line() -> str:
    la = os.getloadavg()
    return f"load average {la[0]:.1f} / {la[1]:.1f} / {la[2]:.1f} (1/5/15 min) on {os.cpu_count()} cores"


def synthetic_cases() -> list[str]:
    return sorted(p.parent.name for p in SYNTHETIC.glob("*/surface.ply"))


def real_cases(need_centerline: bool = False) -> list[tuple[str, Path, Path | None]]:
    """``(key, surface, centerline or None)`` for every real case found (empty, with a note, when none)."""
    out = []
    for key, (surface_file, centerline_file, _) in realdata.REAL_CASES.items():
        s = realdata.real_file(surface_file)
        if s is None:
            continue
        c = realdata.real_file(centerline_file) if centerline_file else None
        if need_centerline and c is None:
            continue
        out.append((key, s, c))
    if not out:
        print(f"note: {realdata.missing_reason()}; real cases skipped", flush=True)
    return out


def skeleton_counts(skeleton) -> dict:
    if skeleton is None:
        return {}
    try:
        n_branches = len(skeleton.branches())
    except Exception:  # pragma: no cover - a bad skeleton is reported elsewhere
        n_branches = None
    return {"nodes": int(skeleton.n_nodes), "edges": int(skeleton.n_edges), "branches": n_branches,
            "junctions": int(len(skeleton.junctions)), "endpoints": int(len(skeleton.endpoints))}


def wall_edge_length(mesh) -> dict:
    """Edge lengths of the wall faces (corner quads) of a hexahedral mesh."""
    q = mesh.corner_boundary_faces()[mesh.boundary_ids == 0]
    p = mesh.points
    e = np.concatenate([np.linalg.norm(p[q[:, i]] - p[q[:, (i + 1) % 4]], axis=1) for i in range(4)])
    return {"mean": float(e.mean()), "median": float(np.median(e)), "min": float(e.min()), "max": float(e.max()), "wall_faces": int(len(q))}


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def mesh_row(case: str, surface, skeleton=None, overrides: dict | None = None, exports: bool = True,
             keep_context: bool = False, label: str = "") -> dict:
    """Run the default chain on one surface (and centerline) and summarise it as one row.

    ``surface`` is a path or a :class:`~vmesh.surface.SurfaceMesh`; ``skeleton`` a path,
    a Skeleton or ``None`` (extracted). ``exports=False`` leaves out the export steps
    (used for the 10^6-node throughput runs). Any exception gives ``status = "failed"``.
    """
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface
    from vmesh.registry import get_filter

    row = {"case": case, "run": label, "status": "ok", "error": "",
           "overrides": dict(overrides or {}), "skeleton_source": "given" if skeleton is not None else "extracted"}
    t0, c0 = time.perf_counter(), _cpu()
    tmp = Path(tempfile.mkdtemp(prefix="vmesh-bench-"))
    ctx = None
    try:
        surf = surface if not isinstance(surface, (str, Path)) else read_surface(surface)
        row["surface_file"] = str(surface) if isinstance(surface, (str, Path)) else (surf.name or "")
        row["surface_nodes"] = int(surf.n_vertices)
        row["surface_elements"] = int(surf.n_faces)
        skel = skeleton
        if isinstance(skeleton, (str, Path)):
            skel = read_skeleton(skeleton)
            row["skeleton_file"] = str(skeleton)
        row["skeleton_in"] = skeleton_counts(skel)
        chain = FilterChain.load("default").with_overrides({**BENCH_OVERRIDES, **(overrides or {})})
        if not exports:
            chain.steps = [s for s in chain.steps if get_filter(s.filter).category != "export"]
        from vmesh.context import Context

        ctx = Context()
        chain.run(surface=surf, skeleton=skel, out_dir=tmp / "out" if exports else None, context=ctx)
    except Exception as exc:  # every failure is a row
        row["status"] = "failed"
        msg = str(exc).strip().splitlines()
        first = re.sub(r"\S*vmesh-bench-[^ /]+/(\.[^ /]+/)?", "", msg[0] if msg else "")  # the deleted temp folder
        row["error"] = f"{type(exc).__name__}: {first}"[:400]
        row["traceback_tail"] = traceback.format_exc().strip().splitlines()[-3:]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    row["wall_s"] = round(time.perf_counter() - t0, 3)
    row["cpu_s"] = round(_cpu() - c0, 3)  # CPU seconds of this process (all threads): less sensitive to other jobs
    if ctx is not None:
        _fill_from_context(row, ctx)
        if keep_context:
            row["_ctx"] = ctx
    return row


def _fill_from_context(row: dict, ctx) -> None:
    stages = {k: 0.0 for k in STAGE_ORDER}
    steps = {}
    peak = 0.0
    for s in ctx.report.steps:
        stages[STAGES.get(s.filter, "export")] += s.seconds
        key, k = s.filter, 2
        while key in steps:
            key, k = f"{s.filter}#{k}", k + 1
        steps[key] = round(s.seconds, 4)
        peak = max(peak, s.peak_memory_mb)
        if s.filter == "resample_skeleton":
            row["skeleton_nodes_resampled"] = s.counts.get("nodes")
        if s.filter == "extract_skeleton":
            row["skeleton_extracted_nodes"] = s.counts.get("nodes")
        if s.warnings:
            row.setdefault("warnings", []).extend(f"{s.filter}: {w}" for w in s.warnings)
    row["stage_s"] = {k: round(v, 3) for k, v in stages.items()}
    row["step_s"] = steps
    row["chain_s"] = round(sum(s.seconds for s in ctx.report.steps), 3)
    row["peak_memory_mb"] = round(peak, 1)
    row["failed_step"] = None
    if row["status"] == "failed":
        names = [s.filter for s in ctx.report.steps]
        row["failed_step"] = f"after {names[-1]}" if names else "first step"
    unt = ctx.report.sections.get("untangle")
    if isinstance(unt, dict):
        row["untangle"] = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in unt.items()
                           if isinstance(v, (int, float, str, bool, np.generic))}
    folds = (ctx.report.sections.get("quality") or {}).get("wall_fold_blocks")
    if folds:  # is the mesh's worst in the blocks the builder found folding on the wall?
        row["wall_fold_blocks"] = folds
    if ctx.skeleton is not None:
        row["skeleton_used"] = skeleton_counts(ctx.skeleton)
    if ctx.blocks is not None:
        row["blocks"] = int(len(ctx.blocks.hexes))
    if ctx.mesh is not None:
        row["elements"] = int(ctx.mesh.n_cells)
        row["nodes"] = int(ctx.mesh.n_points)
        row["order"] = int(ctx.mesh.order)
        try:
            row["wall_edge"] = wall_edge_length(ctx.mesh)
        except Exception:
            pass
        hex_s = steps.get("mesh_transfinite")
        if hex_s:
            row["transfinite_nodes_per_s"] = round(ctx.mesh.n_points / hex_s)
    if ctx.quality:
        sj = np.asarray(ctx.quality["scaled_jacobian"])
        summ = ctx.quality["summary"]
        row["sj_min"] = float(summ["min"])
        row["sj_mean"] = float(summ["mean"])
        row["sj_p01"] = float(summ.get("p01", np.quantile(sj, 0.01)))
        row["invalid"] = int(summ["n_invalid"])
        row["sj_hist"] = np.histogram(np.clip(sj, -1, 1), SJ_BINS)[0].tolist()
        bd = ctx.quality.get("boundary_distance", {})
        row["bdist_max_rel"] = float(bd.get("max_rel", np.nan))
        row["bdist_mean_rel"] = float(bd.get("mean_rel", np.nan))
        row["bdist_max"] = float(bd.get("max", np.nan))
        row["_sj"] = sj


def check_targets(row: dict, sj_min: float = 0.2, sj_mean: float = 0.85, missing_passes: bool = True) -> list[str]:
    """The acceptance criteria for one row (0 invalid elements, min and mean scaled
    Jacobian at least ``sj_min`` and ``sj_mean``) as a list of misses (empty: passed); a
    row without a quality passes unless ``missing_passes`` is false (robustness.judge)."""
    if row["status"] != "ok":
        return [f"failed: {row.get('error', '')}"]
    miss = []
    if row.get("invalid", 0):
        miss.append(f"{row['invalid']} invalid elements")
    for key, least, what in (("sj_min", sj_min, "min"), ("sj_mean", sj_mean, "mean")):
        value = row.get(key)
        if (value is None and not missing_passes) or (value is not None and value < least):
            miss.append(f"{what} SJ {fmt(value, '.3f')} < {least}")
    return miss


def fmt(v, spec=""):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    if spec:
        return format(v, spec)
    if isinstance(v, int):
        return f"{v:,}"
    return str(v)


def table(head: list[str], lines: list[list[str]]) -> str:
    """Print an aligned text table and return it as Markdown."""
    cells = [head] + lines
    widths = [max(len(str(line[i])) for line in cells) for i in range(len(head))]
    for k, line in enumerate(cells):
        print("  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(line, widths))), flush=True)
        if k == 0:
            print("  ".join("-" * w for w in widths))
    md = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    md += ["| " + " | ".join(str(c).replace("|", "/") for c in line) + " |" for line in lines]
    return "\n".join(md)


def clean_rows(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]


def write_results(name: str, rows: list[dict], markdown: str, header: str, extra: dict | None = None) -> tuple[Path, Path]:
    RESULTS.mkdir(parents=True, exist_ok=True)
    js = RESULTS / f"{name}.json"
    md = RESULTS / f"{name}.md"
    payload = {"benchmark": name, "when": time.strftime("%Y-%m-%d %H:%M:%S"), "load": load_line(),
               "python": sys.version.split()[0], "vmesh_source_sha1": source_fingerprint(), **(extra or {}), "rows": clean_rows(rows)}
    write_text_atomic(js, json.dumps(payload, indent=1, default=_json_default))
    write_text_atomic(md, header.rstrip() + f" Source fingerprint `{payload['vmesh_source_sha1']}` (SHA-1 of vmesh/**/*.py and filters/*.toml; "
                      "the fingerprint identifies the code that produced them).\n\n" + markdown.rstrip() + "\n")
    return js, md


def write_quality_results(name: str, rows: list[dict], markdown: str, misses: list[str], png, header: str) -> tuple[Path, Path]:
    """``write_results`` with the quality-target footer and the histogram figure linked."""
    footer = "\n\nQuality (0 invalid, min SJ ≥ 0.2, mean ≥ 0.85): " + ("all rows pass.\n" if not misses else "\n\n" + "\n".join(misses) + "\n")
    js, md = write_results(name, rows, markdown + footer + (f"\n![histograms]({png.name})\n" if png else ""), header)
    print(f"\nwritten {js.relative_to(ROOT)}, {md.name}" + (f", {png.name}" if png else ""))
    return js, md


def source_fingerprint() -> str:
    """SHA-1 of vmesh/**/*.py and filters/*.toml (the meshing code may change between runs)."""
    import hashlib

    h = hashlib.sha1()
    for p in sorted([*(ROOT / "vmesh").rglob("*.py"), *(ROOT / "filters").glob("*.toml")]):
        h.update(p.relative_to(ROOT).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def histogram_figure(panels: list[tuple[str, list[tuple[str, np.ndarray]]]], path: Path, title: str = "") -> Path | None:
    """Scaled Jacobian histograms, one panel per case, side by side (like the paper's Fig. 10).

    ``panels``: ``(panel title, [(series label, scaled jacobians), ...])``.
    """
    panels = [p for p in panels if any(s is not None and len(s) for _, s in p[1])]
    if not panels:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.3 * rows), squeeze=False)
    bins = np.linspace(0, 1, 41)
    for ax, (ptitle, series) in zip(axes.ravel(), panels):
        for k, (label, sj) in enumerate(series):
            if sj is None or not len(sj):
                continue
            w = np.full(len(sj), 100.0 / len(sj))
            kw = {"histtype": "stepfilled", "alpha": 0.55} if k == 0 else {"histtype": "step", "linewidth": 1.5}
            ax.hist(np.clip(sj, 0, 1), bins=bins, weights=w, label=f"{label} (min {sj.min():.2f}, mean {sj.mean():.2f})", **kw)
        ax.set_title(ptitle, fontsize=9)
        ax.set_xlabel("scaled Jacobian")
        ax.set_ylabel("% of elements")
        ax.set_xlim(0, 1)
        ax.legend(fontsize=7, loc="upper left")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def progress_line(row: dict) -> str:
    if row["status"] != "ok":
        return f"  {row['case']} {row.get('run', '')}: FAILED after {row['wall_s']:.1f} s: {row['error']}"
    return (f"  {row['case']} {row.get('run', '')}: {row.get('blocks', 0):,} blocks, {row.get('elements', 0):,} elements, "
            f"{row.get('nodes', 0):,} nodes, SJ min {row.get('sj_min', float('nan')):.3f} mean {row.get('sj_mean', float('nan')):.3f}, "
            f"invalid {row.get('invalid', 0)}, {row['wall_s']:.1f} s")
