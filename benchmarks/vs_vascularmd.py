"""vmesh against vascularmd (Decroocq et al. 2023) on vascularmd's own case, side by side.

In one run on this machine:

1. vascularmd meshes the internal carotid of its example centerline (``ica_centerline.swc``)
   with its own runner (``../shared/peers/vascularmd_ica.py``: 48 nodes around, 4 + 4
   layers, ~400,000 hexahedra), in its own venv, with one BLAS/OpenMP thread (it is 4-8x
   slower with default threading on 2 cores);
2. vmesh meshes, from the same SWC and at the same resolution (``elements_around=6`` per
   block edge = 48 around, ``elements_ring=4``, ``elements_layer=4``, ``element_length=0.25``),
   vascularmd's own surface of this vessel (its ``ica_surface.vtp``, 4 open ends) and the
   shared ``ica_swc_surface.vtp``, each as a whole ``vmesh run`` process;
3. both volume meshes are read back from their files with meshio and rated by ONE scaled
   Jacobian routine written here (Verdict's definition: the minimum over the 8 corners and
   the centre of the normalised Jacobian determinant), independent of both meshers' own.

Times are whole-process wall clocks (interpreter start to exit, so imports count) plus
each tool's own per-stage times. The numba cache is warm after the first vmesh run of a
checkout; ``--repeat N`` keeps the best of N runs per tool. The machine is shared: the load
average is printed with the table, and the rows of one run are measured back to back.

vascularmd's venv is looked for at ``$VASCULARMD_VENV``, then ``../vascularmd-venv`` beside
the repository; its runner at ``$VASCULARMD_PEERS`` then ``../shared/peers``. Where either is
absent the benchmark says so and skips vascularmd (the vmesh rows still run).

Usage::

    python benchmarks/vs_vascularmd.py                 # ~1-2 min
    python benchmarks/vs_vascularmd.py --repeat 3
    python benchmarks/vs_vascularmd.py --unoptimised   # adds vmesh rows without untangling

Writes ``benchmarks/results/vs_vascularmd.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402

ROOT = C.ROOT

#: vmesh settings matching vascularmd's ICA example (48 around = 8 block edges x 6; 4 + 4 layers).
VMESH_SETTINGS = {
    "mesh_transfinite.elements_around": 6,
    "mesh_transfinite.elements_ring": 4,
    "mesh_transfinite.elements_layer": 4,
    "mesh_transfinite.element_length": 0.25,
    "compute_quality.fail_on_invalid": "false",  # inverted elements are counted, not raised
}

#: Extra settings of the ``--unoptimised`` rows (the mesh before any untangling).
UNOPTIMISED = {"mesh_transfinite.untangle": "false"}

#: Corner k of a VTK hexahedron and its three edge neighbours, in right-handed order.
HEX_CORNERS = np.array([[0, 1, 3, 4], [1, 2, 0, 5], [2, 3, 1, 6], [3, 0, 2, 7],
                        [4, 7, 5, 0], [5, 4, 6, 1], [6, 5, 7, 2], [7, 6, 4, 3]])


# ----------------------------------------------------------------------------- quality
def hex_scaled_jacobian(points: np.ndarray, hexes: np.ndarray, chunk: int = 200_000) -> np.ndarray:
    """Scaled Jacobian of linear hexahedra (VTK node order), Verdict's definition.

    The minimum over the 8 corners (three edges from the corner) and the centre (the three
    principal axes) of ``det[a, b, c] / (|a| |b| |c|)``; degenerate edges give 0.

    Parameters
    ----------
    points : (n, 3) float
    hexes : (m, 8) int, VTK hexahedron order (or the 8 corners of a Lagrange hexahedron)

    Returns
    -------
    (m,) float in [-1, 1]
    """
    out = np.empty(len(hexes))
    for s in range(0, len(hexes), chunk):
        p = points[hexes[s:s + chunk]]  # (c, 8, 3)
        e = p[:, HEX_CORNERS[:, 1:], :] - p[:, HEX_CORNERS[:, :1], :]  # (c, 8, 3 edges, 3)
        centre = np.stack([
            (p[:, 1] + p[:, 2] + p[:, 5] + p[:, 6]) - (p[:, 0] + p[:, 3] + p[:, 4] + p[:, 7]),
            (p[:, 2] + p[:, 3] + p[:, 6] + p[:, 7]) - (p[:, 0] + p[:, 1] + p[:, 4] + p[:, 5]),
            (p[:, 4] + p[:, 5] + p[:, 6] + p[:, 7]) - (p[:, 0] + p[:, 1] + p[:, 2] + p[:, 3]),
        ], axis=1)[:, None]  # (c, 1, 3, 3)
        e = np.concatenate([e, centre], axis=1)  # (c, 9, 3, 3)
        det = np.einsum("...i,...i->...", e[..., 0, :], np.cross(e[..., 1, :], e[..., 2, :]))
        lengths = np.linalg.norm(e, axis=-1).prod(axis=-1)
        tiny = lengths <= 1e-300
        sj = np.where(tiny, 0.0, det / np.where(tiny, 1.0, lengths))
        out[s:s + chunk] = np.clip(sj.min(axis=1), -1.0, 1.0)
    return out


def read_hexahedra(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points and (m, 8) corner ids of every hexahedron of a VTU, read with meshio
    (neither mesher's own reader). Lagrange hexahedra give their 8 corners (VTK's first 8 nodes)."""
    import meshio

    m = meshio.read(path)
    blocks = [c.data[:, :8] for c in m.cells if c.type in ("hexahedron", "hexahedron20", "hexahedron27", "VTK_LAGRANGE_HEXAHEDRON")]
    others = sum(len(c.data) for c in m.cells if c.type not in ("hexahedron", "hexahedron20", "hexahedron27", "VTK_LAGRANGE_HEXAHEDRON"))
    if others:
        print(f"  note: {path.name}: {others} non-hexahedral cells left out of the quality", flush=True)
    return np.asarray(m.points, float), np.concatenate(blocks).astype(np.int64)


def quality_summary(path: Path) -> dict:
    points, hexes = read_hexahedra(path)
    sj = hex_scaled_jacobian(points, hexes)
    return {"hexahedra": int(len(hexes)), "nodes": int(len(points)), "sj_min": float(sj.min()), "sj_mean": float(sj.mean()),
            "sj_p01": float(np.quantile(sj, 0.01)), "sj_p05": float(np.quantile(sj, 0.05)),
            "sj_median": float(np.median(sj)), "inverted": int((sj <= 0).sum()), "below_0.3": int((sj < 0.3).sum()),
            "_sj": sj}


# ----------------------------------------------------------------------------- peers
def find_vascularmd() -> tuple[Path | None, Path | None, str]:
    """``(python of vascularmd's venv, its ICA runner, reason when absent)``."""
    env = os.environ.get("VASCULARMD_VENV")
    venvs = [Path(env)] if env else []
    venvs.append(ROOT.parent / "vascularmd-venv")
    python = next((v / "bin" / "python" for v in venvs if (v / "bin" / "python").exists()), None)
    env = os.environ.get("VASCULARMD_PEERS")
    peers = [Path(env)] if env else []
    peers.append(ROOT.parent / "shared" / "peers")
    runner = next((p / "vascularmd_ica.py" for p in peers if (p / "vascularmd_ica.py").is_file()), None)
    if python is None:
        return None, runner, f"vascularmd's venv not found ({', '.join(map(str, venvs))}); set it up per ../shared/peers/README.md or set $VASCULARMD_VENV"
    if runner is None:
        return python, None, f"vascularmd's runner vascularmd_ica.py not found in {', '.join(map(str, peers))}; set $VASCULARMD_PEERS"
    return python, runner, ""


def run_vascularmd(python: Path, runner: Path, out: Path, timeout: float) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    env.pop("PYTHONPATH", None)
    t0 = time.perf_counter()
    try:
        p = subprocess.run([str(python), str(runner), str(out)], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"tool": "vascularmd", "status": "failed", "error": f"timeout after {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"tool": "vascularmd", "status": "failed", "error": f"exit {p.returncode}: {tail[0][:300]}", "wall_s": round(wall, 3)}
    own = json.loads(lines[-1])
    steps = own["steps_s"]
    stages = {"import": steps.get("import", 0.0), "model": own["phases_s"]["model"], "surface": own["phases_s"]["surface"],
              "volume": own["phases_s"]["volume"]}
    stages["write+other"] = max(wall - sum(stages.values()), 0.0)
    return {"tool": "vascularmd", "status": "ok", "wall_s": round(wall, 3), "stage_s": {k: round(v, 3) for k, v in stages.items()},
            "own_quality": {"sj_min": own["scaled_jacobian_min"], "sj_mean": own["scaled_jacobian_mean"]},
            "mesh": out / "ica_volume.vtu", "surface": out / "ica_surface.vtp"}


def run_vmesh(label: str, surface: Path, centerline: Path, out: Path, settings: dict, timeout: float) -> dict:
    cmd = [sys.executable, "-m", "vmesh", "run", "default", "-i", str(surface), "-s", str(centerline), "-o", str(out), "-q"]
    for k, v in settings.items():
        cmd += ["--set", f"{k}={v}"]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"tool": label, "status": "failed", "error": f"timeout after {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    if p.returncode:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
        row = {"tool": label, "status": "failed", "error": f"exit {p.returncode}: {tail[0][:300]}", "wall_s": round(wall, 3)}
        # the failure log lies in this run's temporary folder: keep its end with the row
        log = re.search(r"(\S+failure\.log)", p.stderr or "")
        if log and Path(log.group(1)).is_file():
            row["failure_log_tail"] = Path(log.group(1)).read_text(errors="replace").splitlines()[-25:]
            print("\n".join(f"    {ln}" for ln in row["failure_log_tail"]), file=sys.stderr)
        return row
    report = json.loads((out / "report.json").read_text())
    stages = {"import+start": max(wall - report["total_s"], 0.0)}
    for name, seconds in report["timings"].items():
        key = C.STAGES.get(name, "export")
        stages[key] = stages.get(key, 0.0) + seconds
    row = {"tool": label, "status": "ok", "wall_s": round(wall, 3), "stage_s": {k: round(v, 3) for k, v in stages.items()},
           "step_s": {k: round(v, 3) for k, v in report["timings"].items()},
           "own_quality": {"sj_min": report["quality"]["scaled_jacobian"]["min"], "sj_mean": report["quality"]["scaled_jacobian"]["mean"]},
           "mesh": out / "mesh.vtu", "surface": surface, "warnings": report.get("warnings", [])}
    if isinstance(report.get("untangle"), dict):
        row["untangle"] = report["untangle"]
    return row


# ----------------------------------------------------------------------------- main
def best_of(n: int, run) -> dict:
    rows = [run(k) for k in range(n)]
    ok = [r for r in rows if r["status"] == "ok"]
    best = min(ok, key=lambda r: r["wall_s"]) if ok else rows[-1]
    best["walls_s"] = [r.get("wall_s") for r in rows]
    return best


def report(rows: list[dict], load_before: str) -> str:
    ok = [r for r in rows if r["status"] == "ok"]
    head = ["run", "wall s", "hexahedra", "SJ min", "SJ mean", "SJ p01", "inverted", "SJ<0.3", "own min/mean"]
    lines = []
    for r in rows:
        if r["status"] != "ok":
            lines.append([r["tool"], C.fmt(r.get("wall_s")), "failed", r["error"], "", "", "", "", ""])
            continue
        q = r["quality"]
        lines.append([r["tool"], f"{r['wall_s']:.2f}", f"{q['hexahedra']:,}", f"{q['sj_min']:.3f}", f"{q['sj_mean']:.3f}",
                      f"{q['sj_p01']:.3f}", str(q["inverted"]), str(q["below_0.3"]),
                      f"{r['own_quality']['sj_min']:.3f} / {r['own_quality']['sj_mean']:.3f}"])
    print()
    md = C.table(head, lines)
    peer = next((r for r in ok if r["tool"] == "vascularmd"), None)
    ratios = []
    if peer:
        for r in ok:
            if r is not peer:
                ratios.append(f"{r['tool']}: {peer['wall_s'] / r['wall_s']:.2f}x vascularmd's speed "
                              f"({r['wall_s']:.2f} s vs {peer['wall_s']:.2f} s)")
    if ratios:
        print("\ntime ratio (vascularmd wall / vmesh wall):\n  " + "\n  ".join(ratios))
        md += "\n\nTime ratio (vascularmd wall / vmesh wall):\n\n" + "\n".join(f"- {s}" for s in ratios)
    print("\nseconds per stage:")
    stage_lines = []
    for r in ok:
        stage_lines.append([r["tool"], ", ".join(f"{k} {v:.2f}" for k, v in r["stage_s"].items())])
    md += "\n\nSeconds per stage (each tool's own stages; import+start / write+other = process wall minus the timed stages):\n\n"
    md += C.table(["run", "stages (s)"], stage_lines)
    md += f"\n\n{load_before} before the run, {C.load_line()} after."
    return md


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Needs vascularmd's venv ($VASCULARMD_VENV, else ../vascularmd-venv) and its runner ($VASCULARMD_PEERS, "
        "else ../shared/peers); without them the vascularmd row is skipped with the reason and vmesh runs alone. "
        "The ICA surface and centerline come from the real corpus ($VMESH_REAL_DATA, else ../shared/data/real).",
    )
    ap.add_argument("--repeat", type=int, default=1, help="runs per tool, the fastest kept (default 1)")
    ap.add_argument("--timeout", type=float, default=600, help="seconds per run before it counts as failed")
    ap.add_argument("--unoptimised", action="store_true", help="add vmesh rows without untangling (inverted elements before optimisation)")
    ap.add_argument("--no-write", action="store_true", help="print only, leave benchmarks/results alone")
    args = ap.parse_args(argv)

    from vmesh import realdata

    load_before = C.load_line()
    print(load_before, flush=True)
    swc = realdata.real_file("ica_centerline.swc")
    swc_surface = realdata.real_file("ica_swc_surface.vtp")
    if swc is None:
        print(f"skipped: {realdata.missing_reason()} (ica_centerline.swc)")
        return 0
    python, runner, reason = find_vascularmd()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="vs-vascularmd-") as tmp:
        tmp = Path(tmp)
        peer_surface = None
        if reason:
            print(f"vascularmd skipped: {reason}", flush=True)
        else:
            print(f"vascularmd: {python} {runner} (1 BLAS thread) ...", flush=True)
            peer = best_of(args.repeat, lambda k: run_vascularmd(python, runner, tmp / f"vascularmd_{k}", args.timeout))
            rows.append(peer)
            if peer["status"] == "ok":
                peer_surface = peer["surface"]
            else:
                print(f"  vascularmd failed: {peer['error']}", flush=True)
        cases = []
        if peer_surface is not None:
            cases.append(("vmesh (vascularmd's surface)", peer_surface))
        if swc_surface is not None:
            cases.append(("vmesh (ica_swc_surface.vtp)", swc_surface))
        for label, surface in cases:
            variants = [(label, VMESH_SETTINGS)]
            if args.unoptimised:
                variants.append((label + ", no untangling", {**VMESH_SETTINGS, **UNOPTIMISED}))
            for name, settings in variants:
                print(f"{name} ...", flush=True)
                slug = "".join(ch if ch.isalnum() else "_" for ch in name)
                rows.append(best_of(args.repeat, lambda k: run_vmesh(name, surface, swc, tmp / f"{slug}_{k}", settings, args.timeout)))
        for r in rows:
            if r["status"] == "ok":
                r["quality"] = quality_summary(Path(r["mesh"]))
            else:
                print(f"  {r['tool']} failed: {r['error']}", flush=True)
    md = report(rows, load_before)
    for r in rows:
        r.pop("mesh", None)
        if "surface" in r:
            r["surface"] = str(r["surface"])
        if "quality" in r:
            r["quality"] = {k: v for k, v in r["quality"].items() if not k.startswith("_")}
    if not args.no_write:
        header = ("# vmesh vs vascularmd on vascularmd's ICA case\n\n"
                  "Written by `python benchmarks/vs_vascularmd.py`. Whole-process wall times on a shared 2-core machine "
                  "(noisy: compare the rows of one run, measured back to back); quality of both meshes by the benchmark's "
                  "own scaled-Jacobian routine on the files read with meshio; `own` = each tool's self-reported min / mean.")
        js, mdp = C.write_results("vs_vascularmd", rows, md, header,
                                  extra={"vmesh_settings": VMESH_SETTINGS, "skipped": reason or None})
        print(f"\nwritten {js.relative_to(ROOT)}, {mdp.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
