"""Did a restructuring change any mesh? Element counts and scaled-Jacobian digests per case.

Runs the default chain (refinement 1, no exports) on a fixed list of cases: every synthetic
case with its known skeleton (as ``mesh_cases``), three of them with the skeleton extracted
(extraction and cleaning are exercised), and four small real surfaces. For each case it keeps
the element count, min / mean scaled Jacobian, a SHA-1 of the sorted ``np.round(sj, 12)``
(equal digests: the same qualities to 1e-12), and a SHA-1 of the skeleton that reached
the block builder (points rounded to 1e-9, edges).

Usage::

    python benchmarks/restructure_check.py --out /tmp/new.json
    python benchmarks/restructure_check.py --out /tmp/new.json --compare benchmarks/results/restructure_base.json
    python benchmarks/restructure_check.py --compare OLD.json NEW.json       # compare two files, run nothing
    python benchmarks/restructure_check.py --cases y_bifurcation real_carotid --out /tmp/x.json

The committed base, ``benchmarks/results/restructure_base.json``, is main at 7651fb6 (before
the codebase round); run the script after a merge and compare against it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402

#: Synthetic cases also run with the skeleton extracted from the surface.
EXTRACTED = ("y_bifurcation", "trifurcation", "two_junctions")
#: ``(name, realdata key, skeleton given)``: small real surfaces (a few seconds each).
REAL = (("real_carotid", "carotid", True), ("real_carotid_extracted", "carotid", False),
        ("real_aorta_simvascular", "aorta_simvascular", True), ("real_aneurysm_extracted", "aneurysm", False))


def cases() -> list[tuple[str, Path, Path | None]]:
    """``(name, surface, skeleton or None)`` of every case available here."""
    out = [(n, C.SYNTHETIC / n / "surface.ply", C.SYNTHETIC / n / "skeleton.json") for n in C.synthetic_cases()]
    out += [(f"{n}_extracted", C.SYNTHETIC / n / "surface.ply", None) for n in EXTRACTED]
    real = {k: (s, c) for k, s, c in C.real_cases()}
    out += [(name, real[key][0], real[key][1] if given else None) for name, key, given in REAL
            if key in real and (real[key][1] is not None or not given)]
    return out


def digest(a: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def summarise(name: str, surface: Path, skeleton: Path | None) -> dict:
    """One row: status, element count, SJ min / mean and digests of the qualities and skeleton."""
    row = C.mesh_row(name, surface, skeleton, exports=False, keep_context=True)
    out = {"case": name, "skeleton": "given" if skeleton else "extracted", "status": row["status"],
           "error": row.get("error", ""), "elements": row.get("elements"), "cpu_s": row.get("cpu_s")}
    sj = row.get("_sj")
    if sj is not None:
        out.update(sj_min=float(np.min(sj)), sj_mean=float(np.mean(sj)),
                   sj_digest=digest(np.sort(np.round(np.asarray(sj, dtype=np.float64), 12))))
    ctx = row.get("_ctx")
    sk = getattr(ctx, "skeleton", None)
    if sk is not None:
        out.update(skeleton_nodes=int(sk.n_nodes), skeleton_digest=digest(np.concatenate(
            [np.round(np.asarray(sk.points, np.float64), 9).ravel(), np.asarray(sk.edges, np.float64).ravel()])))
    return out


def compare(old: dict, new: dict) -> int:
    """Print a table of the cases that changed; return how many did."""
    before = {r["case"]: r for r in old["rows"]}
    changed = 0
    print(f"{'case':28s} {'elements old→new':>20s} {'SJ min old→new':>18s} {'SJ digest':>10s} {'skeleton':>9s}")
    for r in new["rows"]:
        o = before.get(r["case"])
        if o is None:
            print(f"{r['case']:28s} (not in the old file)")
            continue
        same_sj = o.get("sj_digest") == r.get("sj_digest") and o["status"] == r["status"]
        same_sk = o.get("skeleton_digest") == r.get("skeleton_digest")
        same = same_sj and same_sk and o.get("elements") == r.get("elements")
        changed += not same
        mins = f"{o.get('sj_min', float('nan')):.4f}→{r.get('sj_min', float('nan')):.4f}"
        print(f"{r['case']:28s} {str(o.get('elements')) + '→' + str(r.get('elements')):>20s} {mins:>18s} "
              f"{'same' if same_sj else 'CHANGED':>10s} {'same' if same_sk else 'CHANGED':>9s}")
    print(f"\n{changed} of {len(new['rows'])} cases changed")
    return changed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="case names (default: all)")
    ap.add_argument("--out", type=Path, help="JSON to write (default: print only)")
    ap.add_argument("--compare", nargs="+", type=Path, metavar="JSON",
                    help="OLD.json: compare this run against it; OLD.json NEW.json: compare two files, run nothing")
    args = ap.parse_args(argv)
    if args.compare and len(args.compare) == 2:
        return int(compare(*(json.loads(p.read_text()) for p in args.compare)) > 0)
    todo = [c for c in cases() if not args.cases or c[0] in args.cases]
    rows = []
    for i, (name, surface, skeleton) in enumerate(todo):
        rows.append(summarise(name, surface, skeleton))
        r = rows[-1]
        print(f"[{i + 1}/{len(todo)}] {name}: {r['status']} {r.get('elements')} elements, "
              f"SJ min {r.get('sj_min', float('nan')):.4f}, {r.get('cpu_s')} s CPU", flush=True)
    result = {"benchmark": "restructure_check", "when": time.strftime("%Y-%m-%d %H:%M:%S"),
              "vmesh_source_sha1": C.source_fingerprint(), "rows": rows}
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))
        print(f"written {args.out}")
    if args.compare:
        return int(compare(json.loads(args.compare[0].read_text()), result) > 0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
