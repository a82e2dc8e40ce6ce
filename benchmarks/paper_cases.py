"""Analogues of the paper's three cases (aneurysm, coarctation, cerebral tree), fine and coarse SDF.

The paper meshes a cerebral aneurysm (~11 skeleton nodes, ~4k-triangle surface), an aortic
coarctation (~58 nodes, ~160k triangles) and a cerebral tree (~576 nodes, ~100k
triangles). The analogues:

==========================  ==================================================================
``aneurysm_synthetic``      data_synthetic/aneurysm (14k triangles) decimated to 4,000
                            triangles at benchmark time (``decimate_surface``, pymeshlab),
                            its known skeleton (23 nodes)
``aneurysm_real``           ../shared/data/real/aneurysm_ica_aneurisk_c0015_open.vtp (7.5k
                            triangles, 3 open ends), skeleton extracted
``coarctation_synthetic``   data_synthetic/coarctation regenerated at 160,000 triangles by
                            ``data_synthetic/generate.py`` (``CaseSpec.target_faces``; the
                            committed file has 20k), its known skeleton (63 nodes)
``coarctation_real``        ../shared/data/real/coarctation_bpm120_open.stl (77k triangles,
                            5 open ends), skeleton extracted
``cerebral_tree``           data_synthetic/cerebral_tree as committed (100k triangles, 524
                            skeleton nodes)
==========================  ==================================================================

Each runs the default chain twice: ``sdf=coarse`` (the default: SDF of the decimated
surface, projections refined on the fine one) and ``sdf=fine`` (``build_sdf.source=fine``,
``refine_on_fine=false``). Columns: the paper's Table 1 (skeleton nodes and segments =
edges / branches, surface nodes and elements), blocks, elements, nodes, seconds per stage,
scaled Jacobian min / mean, invalid elements, boundary distance (relative to the radius).

Usage::

    python benchmarks/paper_cases.py             # all five cases, both SDFs (~5 min)
    python benchmarks/paper_cases.py --quick     # the two aneurysms only
    python benchmarks/paper_cases.py --cases cerebral_tree --sdf coarse

Writes ``benchmarks/results/paper_cases.json``, ``.md`` and ``paper_cases_sj.png`` (the
histograms side by side, like the paper's Fig. 10).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402
from vmesh import realdata  # noqa: E402

SDF = {
    "coarse": {},  # the default chain: coarse SDF + refine_on_fine
    "fine": {"build_sdf.source": "fine", "build_sdf.refine_on_fine": False},
}
PAPER = {"aneurysm": "≈11 nodes, ≈4k triangles", "coarctation": "≈58 nodes, ≈160k triangles", "cerebral_tree": "≈576 nodes, ≈100k triangles"}


def _decimated(path, faces):
    from vmesh.chain import FilterChain

    ctx = FilterChain([("decimate_surface", {"target_faces": int(faces), "output": "surface"})]).run(surface=path)
    ctx.surface.name = f"{Path(path).parent.name} decimated to {faces}"
    return ctx.surface


def _regenerated(name, faces):
    sys.path.insert(0, str(C.SYNTHETIC))
    from data_synthetic import generate
    from vmesh.surface import SurfaceMesh

    spec = generate.case_spec(name)
    spec.target_faces = int(faces)
    V, F = generate.surface_from_spec(spec)
    V = V.astype("float32").astype("float64")
    return SurfaceMesh(V, F, name=f"{name} regenerated at {faces}")


def case_list():
    """``(name, paper case, how the surface was made, surface factory, skeleton or None)``."""
    out = [
        ("aneurysm_synthetic", "aneurysm", "data_synthetic/aneurysm decimated 14k→4k",
         lambda: _decimated(C.SYNTHETIC / "aneurysm" / "surface.ply", 4000), C.SYNTHETIC / "aneurysm" / "skeleton.json"),
    ]
    p = realdata.real_file("aneurysm_ica_aneurisk_c0015_open.vtp")
    if p is not None:
        out.append(("aneurysm_real", "aneurysm", "aneurysm_ica_aneurisk_c0015_open.vtp as is", lambda p=p: p, None))
    out.append(("coarctation_synthetic", "coarctation", "data_synthetic/coarctation regenerated at 160k (generate.py)",
                lambda: _regenerated("coarctation", 160_000), C.SYNTHETIC / "coarctation" / "skeleton.json"))
    p = realdata.real_file("coarctation_bpm120_open.stl")
    if p is not None:
        out.append(("coarctation_real", "coarctation", "coarctation_bpm120_open.stl as is", lambda p=p: p, None))
    out.append(("cerebral_tree", "cerebral_tree", "data_synthetic/cerebral_tree as is",
                lambda: C.SYNTHETIC / "cerebral_tree" / "surface.ply", C.SYNTHETIC / "cerebral_tree" / "skeleton.json"))
    if realdata.real_data_dir() is None:
        print(f"note: {realdata.missing_reason()}; real analogues skipped")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="aneurysm_synthetic aneurysm_real coarctation_synthetic coarctation_real cerebral_tree")
    ap.add_argument("--quick", action="store_true", help="the two aneurysm cases only")
    ap.add_argument("--sdf", nargs="+", default=["coarse", "fine"], choices=list(SDF))
    ap.add_argument("--name", default="paper_cases")
    args = ap.parse_args(argv)
    cases = case_list()
    if args.quick:
        cases = [c for c in cases if c[1] == "aneurysm"]
    if args.cases:
        cases = [c for c in cases if c[0] in args.cases]
    print(f"{len(cases)} cases x {len(args.sdf)} SDFs; {C.load_line()}", flush=True)
    rows = []
    for i, (name, paper, how, make, skeleton) in enumerate(cases):
        print(f"[{i + 1}/{len(cases)}] {name}: preparing surface ({how}) ...", flush=True)
        t0 = time.perf_counter()
        try:
            surface = make()
            prep_s = round(time.perf_counter() - t0, 2)
        except Exception as exc:
            rows.append({"case": name, "paper_case": paper, "surface_how": how, "run": "-", "status": "failed",
                         "error": f"surface preparation: {type(exc).__name__}: {exc}", "wall_s": 0.0})
            print(C.progress_line(rows[-1]), flush=True)
            continue
        for sdf in args.sdf:
            print(f"    {name} sdf={sdf} ...", flush=True)
            row = C.mesh_row(name, surface, skeleton, overrides=SDF[sdf], label=f"sdf={sdf}")
            row.update(paper_case=paper, surface_how=how, surface_prep_s=prep_s, sdf=sdf)
            rows.append(row)
            print(C.progress_line(row), flush=True)

    head = ["case", "SDF", "surface", "skel nodes", "skel segments (edges/branches)", "surf nodes", "surf elements", "blocks",
            "elements", "nodes", "pre s", "sdf s", "skel s", "blocks s", "hex s", "quality s", "export s", "chain s",
            "SJ min", "SJ mean", "invalid", "bdist max/mean %R", "status"]
    lines = []
    for r in rows:
        sk = r.get("skeleton_in") or r.get("skeleton_used") or {}
        src = "given" if r.get("skeleton_in") else "extracted"
        st = r.get("stage_s", {})
        lines.append([
            r["case"], r.get("sdf", "-"), r.get("surface_how", ""),
            f"{C.fmt(sk.get('nodes'))} ({src})", f"{C.fmt(sk.get('edges'))}/{C.fmt(sk.get('branches'))}",
            C.fmt(r.get("surface_nodes")), C.fmt(r.get("surface_elements")), C.fmt(r.get("blocks")), C.fmt(r.get("elements")),
            C.fmt(r.get("nodes")), *[C.fmt(st.get(k), ".2f") for k in C.STAGE_ORDER], C.fmt(r.get("chain_s"), ".1f"),
            C.fmt(r.get("sj_min"), ".3f"), C.fmt(r.get("sj_mean"), ".3f"), C.fmt(r.get("invalid")),
            f"{C.fmt(100 * r['bdist_max_rel'], '.2f')}/{C.fmt(100 * r['bdist_mean_rel'], '.2f')}" if "bdist_max_rel" in r else "-",
            "ok" if r["status"] == "ok" else f"FAILED: {r['error'][:120]}",
        ])
    print()
    md = C.table(head, lines)
    misses = [f"- {r['case']} ({r.get('run')}): " + "; ".join(m) for r in rows if (m := C.check_targets(r))]
    print("\nquality targets (0 invalid, min SJ >= 0.2, mean >= 0.85): " + ("all rows pass" if not misses else "misses:\n" + "\n".join(misses)))

    panels = []
    for name, paper, how, _, _ in cases:
        series = [(r["sdf"] + " SDF", r.get("_sj")) for r in rows if r["case"] == name and "sdf" in r]
        el = next((r.get("elements") for r in rows if r["case"] == name and r.get("elements")), 0)
        panels.append((f"{name}: {el:,} hexes\n(paper: {PAPER[paper]})", series))
    png = C.histogram_figure(panels, C.RESULTS / f"{args.name}_sj.png", title="Scaled Jacobian of the paper's cases' analogues (coarse vs fine SDF)")
    header = (f"# paper_cases\n\n`python benchmarks/paper_cases.py` — {time.strftime('%Y-%m-%d %H:%M')}, {C.load_line()} "
              "(other jobs ran concurrently: times are noisy). Default chain with `compute_quality.fail_on_invalid=false`; "
              "`sdf=coarse` is the default (coarse SDF, projection refined on the fine surface), `sdf=fine` sets "
              "`build_sdf.source=fine, refine_on_fine=false`. Skeleton nodes/segments are the input skeleton's (given) or the "
              "extracted one's (after cleaning and resampling); surface nodes/elements are the input surface's. "
              "Paper's cases: aneurysm ≈11 nodes / ≈4k triangles, coarctation ≈58 / ≈160k, cerebral tree ≈576 / ≈100k.\n")
    C.write_quality_results(args.name, rows, md, misses, png, header)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
