"""``vmesh batch``: mesh every row of a manifest (many geometries, parameter sweeps) on Dask.

Examples
--------
::

    vmesh batch sweep.toml --chain batch_sweep --out out/sweep               # local cluster
    vmesh batch patients.csv --chain default --out out/p --workers 4
    vmesh batch sweep.toml --chain batch_sweep --out out/sweep --scheduler tcp://head:8786
"""

from __future__ import annotations

import sys

from ..cli import EXTRA_COMMANDS, parse_overrides

HELP = "mesh every row of a CSV/TOML manifest (geometries, parameter sweeps) on a Dask cluster"


def add_arguments(p) -> None:
    p.add_argument("manifest", metavar="MANIFEST", help="CSV (surface, skeleton, name, filter.param columns) or TOML (rows and sweeps)")
    p.add_argument("-c", "--chain", help="chain file or preset every row runs (default: the TOML manifest's 'chain', else 'default')")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder: DIR/<name>/ per row, DIR/summary.csv")
    p.add_argument("--scheduler", metavar="ADDRESS", help="submit to a running Dask scheduler (tcp://host:8786) instead of a local cluster")
    p.add_argument("--workers", type=int, metavar="N", help="local cluster: N worker processes (default: one per core); with --scheduler: wait for N workers")
    p.add_argument("--set", action="append", metavar="FILTER.PARAM=VALUE", help="override a parameter in every row (repeatable; manifest columns win)")
    p.add_argument("--retries", type=int, default=1, metavar="N", help="extra attempts of a failed row (default: 1; rows that fail on their input are not retried)")
    p.add_argument("--cache-entries", type=int, default=2, metavar="N", help="preprocessed surfaces + signed distances each worker keeps (default: 2)")
    p.add_argument("--no-parquet", action="store_true", help="write summary.csv only (summary.parquet needs pyarrow)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def run(args) -> int:
    from .. import batch
    from ..errors import InputError

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}")
    if args.retries < 0:
        raise InputError(f"--retries must be at least 0, got {args.retries}")
    manifest = batch.read_manifest(args.manifest)
    chain, overrides = args.chain or manifest.chain or "default", parse_overrides(args.set)
    if overrides:  # a bad --set value is --set's error, not the first row's
        check_overrides(chain, overrides)
    result = batch.run(
        manifest,
        chain,
        out=args.out,
        scheduler=args.scheduler,
        workers=args.workers,
        overrides=overrides,
        retries=args.retries,
        progress=not args.quiet,
        parquet=False if args.no_parquet else "auto",
        cache_entries=args.cache_entries,
    )
    computed = len(result.rows) - result.n_resumed
    print(f"{len(result.rows)} rows: {result.n_ok} ok, {result.n_failed} failed ({result.n_resumed} resumed, {computed} run) in {result.seconds:.1f} s")
    print(f"summary in {result.summary_csv}" + (f" and {result.summary_parquet}" if result.summary_parquet else ""))
    for r in result.rows:
        if r["status"] == "failed":
            print(f"failed: {r['name']}: {r['error']}", file=sys.stderr)
    return 1 if result.n_failed else 0


def check_overrides(chain, overrides: dict) -> None:
    """Refuse a bad ``--set`` before any row runs, as ``--set``'s error: a filter not in the
    chain, an unknown parameter, a value its parameter refuses (``with_overrides`` checks
    each). Only the overridden values are checked: the rows may still supply parameters the
    chain leaves unset (a ``meshlab_script.path`` column), so the chain is not resolved with
    ``--set`` alone."""
    from ..chain import FilterChain
    from ..errors import InputError, VmeshError

    loaded = chain if isinstance(chain, FilterChain) else FilterChain.load(chain)  # its own errors name the chain
    try:
        loaded.with_overrides(overrides)
    except VmeshError as exc:
        raise InputError(f"--set: {exc}") from None


EXTRA_COMMANDS["batch"] = (add_arguments, run, HELP)
