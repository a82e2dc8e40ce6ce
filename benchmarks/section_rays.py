"""The rays of one skeleton node's cross-section in the block builder (for a build that fails
with "cross-section at skeleton node N finds no wall within reach").

Runs the default chain up to ``build_block_structure`` (its context pickled to ``--prefix``
and reused when that file exists), then the builder with hooks on the section rays: for
every build round that places a regular section at ``--node``, prints its branch (nodes,
end kinds, whether the builder takes it for a stub), the section's radius, and its ray
lengths as cast in the closed surface, after clipping to the section's own vessel
(``_own_territory``) and after cutting at necks (``_through_necks``); ``nan``: no wall
within reach (12 radii). Ends with the build's outcome.

    PYTHONPATH=$PWD python3 benchmarks/section_rays.py SURFACE [--skeleton FILE] --prefix /tmp/x.pkl --node N [--set FILTER.PARAM=VALUE ...]

docs/robustness.md, h21/fold (seed 1 g0004 extracted, real hepatic_artery extracted).
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402


def context_before_build(surface, skeleton, path: Path, overrides: dict):
    """The chain's context before ``build_block_structure`` (pickled to ``path`` with the
    inputs and overrides; a pickle written for others is refused)."""
    from vmesh.chain import FilterChain
    from vmesh.context import Context
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    inputs = {"surface": str(Path(surface).resolve()), "skeleton": str(Path(skeleton).resolve()) if skeleton else None, "overrides": overrides}
    if path.is_file():
        saved = pickle.loads(path.read_bytes())
        if not isinstance(saved, dict) or saved.get("inputs") != inputs:
            raise SystemExit(f"--prefix {path} was written for other inputs; not {inputs}: remove it or pass another --prefix")
        return saved["context"]
    chain = FilterChain.load("default").with_overrides({**C.BENCH_OVERRIDES, **overrides})
    chain.steps = chain.steps[: [s.filter for s in chain.steps].index("build_block_structure")]
    ctx = Context()
    chain.run(surface=read_surface(surface), skeleton=read_skeleton(skeleton) if skeleton else None, out_dir=None, context=ctx)
    path.write_bytes(pickle.dumps({"inputs": inputs, "context": ctx}))
    return ctx


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("surface")
    ap.add_argument("--skeleton", help="a given centerline (default: extracted)")
    ap.add_argument("--prefix", required=True, help="pickle of the chain's context before build_block_structure (written once)")
    ap.add_argument("--node", type=int, required=True, help="the skeleton node whose section rays are printed")
    ap.add_argument("--set", action="append", default=[], metavar="FILTER.PARAM=VALUE", help="a chain parameter (repeatable)")
    args = ap.parse_args(argv)
    from vmesh.cli import parse_overrides
    from vmesh.chain import FilterChain
    from vmesh.geometry.blocks.sections import _Sections
    from vmesh.registry import get_filter

    overrides = parse_overrides(args.set) if args.set else {}
    ctx = context_before_build(args.surface, args.skeleton, Path(args.prefix), overrides)
    own, neck = _Sections._own_territory, _Sections._through_necks

    def show(self, idx, R, label):
        for n, (b, k) in enumerate(idx):
            br = self.topo.branches[b]
            if int(br.nodes[k]) == args.node:
                if label == "cast":
                    print(f"branch {b}: nodes {br.nodes.tolist()}, ends {list(br.kinds)}, stub {self.stub_of(b) is not None}")
                print(f"  {label:14s} {np.round(R[n], 3).tolist()}")

    def hooked_own(self, idx, origin, dirs, R, rad):
        show(self, idx, R, "cast")
        out = own(self, idx, origin, dirs, R, rad)
        show(self, idx, out, "own territory")
        return out

    def hooked_neck(self, idx, origin, dirs, R, rad, is_open):
        out = neck(self, idx, origin, dirs, R, rad, is_open)
        show(self, idx, out, "through necks")
        return out

    _Sections._own_territory, _Sections._through_necks = hooked_own, hooked_neck
    try:
        step = next(s for s in FilterChain.load("default").with_overrides(overrides).steps if s.filter == "build_block_structure")
        get_filter("build_block_structure")(ctx, **step.params)
        print(f"built: {len(ctx.blocks.hexes)} blocks")
    except Exception as exc:  # the failure being probed
        print(f"failed: {exc}")
    finally:
        _Sections._own_territory, _Sections._through_necks = own, neck
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
