"""Batch meshing on Dask: many geometries and parameter sweeps.

A *manifest* (:mod:`vmesh.manifest`) lists the rows to mesh: a surface, an optional skeleton, an optional name
and any number of ``filter.param`` overrides. :func:`run` validates every row, then
meshes the rows on a Dask cluster (a local one by default, or an existing scheduler),
each into its own output folder, and writes ``summary.csv`` (and ``summary.parquet``
when pyarrow is installed) with one row per manifest row.

* **Atomic rows**: a row is run into a hidden staging folder and renamed to
  ``OUT/<name>/`` only when it succeeded; ``OUT/<name>/row.json`` marks it finished.
* **Resume**: re-running the same batch skips finished rows whose inputs and resolved
  chain are unchanged (a changed parameter or surface is recomputed).
* **Failures**: a failed row (an error, or a worker that died) is retried once
  (``retries``), then reported with its error; the other rows go on. A row that fails on
  its input (:class:`~vmesh.errors.InputError`: unreadable, open, wrong units...) fails
  once: a retry reads the same input.
* **Memory**: each worker process keeps a :class:`~vmesh.cache.PrefixCache`, so the
  steps up to the signed distance run once per worker for each distinct surface and
  preprocessing, not once per row.

Examples
--------
>>> import vmesh.batch
>>> result = vmesh.batch.run("sweep.toml", "batch_sweep", out="out/sweep")   # doctest: +SKIP
>>> from distributed import Client
>>> result = vmesh.batch.run("patients.csv", "default", out="out/p", client=Client("tcp://head:8786"))  # doctest: +SKIP
>>> result.n_ok, result.summary_csv                                          # doctest: +SKIP
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import shutil
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError, VmeshError, stop_behind
from .manifest import RESERVED, Manifest, ManifestRow, expand_sweep, manifest_from_rows, read_manifest, sweep_values

__all__ = ["BatchResult", "Manifest", "ManifestRow", "RESERVED", "ROW_FILE", "STAGING", "SUMMARY_COLUMNS", "expand_sweep", "manifest_from_rows", "mesh_row", "prepare", "read_manifest", "read_row", "read_summary", "run", "sweep_values", "worker_cache"]

#: Columns of the summary every row has, in order (override columns follow).
SUMMARY_COLUMNS = ("name", "status", "elements", "sj_min", "sj_mean", "seconds", "error", "attempts", "resumed", "sdf_reused", "worker", "cpu_seconds", "surface", "skeleton")
#: Hidden folder inside the output folder where rows are staged.
STAGING = ".vmesh-batch"
#: Marker file of a finished row.
ROW_FILE = "row.json"
#: Seconds between rewrites of the summary while a batch runs.
_SUMMARY_EVERY_S = 10.0
_NAME_OK = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.=+,-]*$")



# ---------------------------------------------------------------------------
# validation: every problem before anything runs
# ---------------------------------------------------------------------------
@dataclass
class _Task:
    row: ManifestRow
    name: str
    chain_toml: str
    key: str
    overrides: dict


def _file_digest(path: str, memo: dict) -> str:
    st = os.stat(path)
    sig = (path, st.st_size, st.st_mtime_ns)
    if sig not in memo:
        h = hashlib.blake2b(digest_size=16)
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        memo[sig] = h.hexdigest()
    return memo[sig]


def _default_name(row: ManifestRow) -> str:
    # a content hash keeps default names stable when rows are added or reordered
    text = json.dumps([row.surface, row.skeleton, row.overrides], sort_keys=True, default=str)
    return f"{Path(row.surface).stem}-{hashlib.blake2b(text.encode(), digest_size=4).hexdigest()}"


def prepare(manifest: Manifest, chain, overrides: dict | None = None) -> list[_Task]:
    """Check every row and return the tasks to run.

    Checks: input files exist, names are unique and usable as folder names, every
    override names a filter of the chain and one of its parameters with a valid value,
    and the chain has every layer it needs (a row without a skeleton needs a chain that
    extracts one).

    Raises
    ------
    InputError
        ``<manifest>: <row>: <problem>``.
    """
    from .chain import FilterChain
    from .registry import filter_list, get_filter, suggest

    where_file = manifest.path or "manifest"
    chain = chain if isinstance(chain, FilterChain) else FilterChain.load(chain)
    base = chain.with_overrides(overrides or {}) if overrides else chain
    for col in dict.fromkeys([*manifest.columns, *manifest.override_columns]):
        fname, _, pname = col.partition(".")
        steps = [s.filter for s in base.steps]
        if not pname or fname not in steps:
            hint = (f" (add a [[step]] filter = \"{fname}\" to a copy of the chain: docs/chains.md)" if pname and fname in filter_list()
                    else suggest(fname, filter_list()))
            raise InputError(f"column '{col}': no filter '{fname}' in chain '{base.name}'" + hint, where_file)
        try:
            get_filter(fname).parameter(pname)
        except VmeshError as exc:
            raise InputError(f"column '{col}': {exc}", where_file) from None
    memo: dict = {}
    tasks, names = [], {}
    resolved_cache: dict = {}
    for r in manifest.rows:
        for label, p in (("surface", r.surface), ("skeleton", r.skeleton)):
            if p is not None and not Path(p).is_file():
                raise InputError(f"{r.where}: {label} file not found: {p}", where_file)
        name = r.name or _default_name(r)
        if not _NAME_OK.match(name) or len(name) > 200:
            raise InputError(f"{r.where}: name {name!r} is not usable as a folder name (letters, digits and _ . = + , -; not starting with . or -)", where_file)
        if name in names:
            raise InputError(f"{r.where}: name '{name}' is used by {names[name]} too", where_file)
        if name.lower() in ("summary.csv", "summary.parquet"):
            raise InputError(f"{r.where}: name '{name}' is the summary's file name", where_file)
        names[name] = r.where
        sig = json.dumps(r.overrides, sort_keys=True, default=str) + f"|{r.skeleton is not None}"
        if sig not in resolved_cache:
            try:
                row_chain = base.with_overrides(r.overrides).resolved()
                row_chain.check_layers(["surface"] + (["skeleton"] if r.skeleton else []))
            except VmeshError as exc:
                raise InputError(f"{r.where}: {exc}", where_file) from None
            resolved_cache[sig] = row_chain.to_toml("# vmesh batch row chain")
        text = resolved_cache[sig]
        ident = [text, _file_digest(r.surface, memo), _file_digest(r.skeleton, memo) if r.skeleton else None]
        key = hashlib.blake2b(json.dumps(ident).encode(), digest_size=16).hexdigest()
        tasks.append(_Task(r, name, text, key, {**(overrides or {}), **r.overrides}))
    return tasks


# ---------------------------------------------------------------------------
# the task a worker runs
# ---------------------------------------------------------------------------
_WORKER_CACHE = None


def worker_cache(max_entries: int = 2):
    """This process's :class:`~vmesh.cache.PrefixCache` (one per Dask worker process)."""
    global _WORKER_CACHE
    from .cache import PrefixCache

    if _WORKER_CACHE is None:
        _WORKER_CACHE = PrefixCache(max_entries)
    else:
        _WORKER_CACHE.max_entries = max_entries
    return _WORKER_CACHE


def _worker_name() -> str:
    try:
        from distributed import get_worker

        w = get_worker()
        return str(w.name) if w.name is not None else w.address
    except (ImportError, ValueError):
        import socket

        return f"{socket.gethostname()}:{os.getpid()}"


def read_row(folder) -> dict | None:
    """The ``row.json`` of a finished row folder, or ``None``."""
    try:
        return json.loads((Path(folder) / ROW_FILE).read_text())
    except (OSError, ValueError):
        return None


def mesh_row(task: dict) -> dict:
    """Mesh one manifest row (runs on a worker) and return its summary row.

    The chain runs into ``OUT/.vmesh-batch/<name>.<random>/``, which is renamed to
    ``OUT/<name>/`` only after the mesh and ``row.json`` are written: a row folder is
    either complete or absent. Errors are returned as ``status = "failed"``, not raised,
    so that one bad row never stops a batch.
    """
    from .chain import FilterChain

    t0, c0 = time.perf_counter(), time.thread_time()
    out = Path(task["out"])
    name = task["name"]
    final = out / name
    staging = out / STAGING
    tmp = staging / f"{name}.{uuid.uuid4().hex[:10]}"
    result = {"name": name, "status": "failed", "elements": None, "sj_min": None, "sj_mean": None, "seconds": None, "cpu_seconds": None, "error": "", "sdf_reused": False, "worker": _worker_name(), "key": task["key"]}
    try:
        staging.mkdir(parents=True, exist_ok=True)
        chain = FilterChain.from_toml(task["chain"], source=f"row {name}")
        ctx = chain.run(surface=task["surface"], skeleton=task["skeleton"], out_dir=tmp, cache=worker_cache(task.get("cache_entries", 2)))
        rep = ctx.report.to_dict()
        sj = rep.get("quality", {}).get("scaled_jacobian", {})
        elements = rep.get("counts", {}).get("elements")
        if elements is None and ctx.mesh is not None:
            elements = int(getattr(ctx.mesh, "n_cells", 0)) or None
        result.update(
            status="ok",
            elements=elements,
            sj_min=sj.get("min"),
            sj_mean=sj.get("mean"),
            sdf_reused=any(s.cached and s.filter == "build_sdf" for s in ctx.report.steps),
        )
        # CPU time of this thread (the mesher's own threads excluded): wall time on a busy
        # machine says little about the work a row needs
        result["seconds"], result["cpu_seconds"] = round(time.perf_counter() - t0, 3), round(time.thread_time() - c0, 3)
        record = {**result, "surface": task["surface"], "skeleton": task["skeleton"], "overrides": task["overrides"], "warnings": rep.get("warnings", [])}
        tmp.mkdir(parents=True, exist_ok=True)  # a chain without output files still gets its folder
        (tmp / ROW_FILE).write_text(json.dumps(record, indent=2, default=str))
        _commit_row(tmp, final, staging, task["key"])
        done = read_row(final)
        if done is not None and done.get("key") == task["key"] and done.get("status") == "ok":
            return {k: done.get(k, v) for k, v in result.items()}  # a twin attempt may have finished first
        return result
    except Exception as exc:  # reported in the summary; the batch goes on
        shutil.rmtree(tmp, ignore_errors=True)
        stop = stop_behind(exc)
        if stop is not None:  # a stop, not this row's failure
            raise stop from None
        result["status"] = "failed"
        result["retry"] = not isinstance(exc, InputError)  # the same file fails the same way again
        result["error"] = " ".join(f"{exc}".split()) if isinstance(exc, VmeshError) else " ".join(f"{type(exc).__name__}: {exc}".split())
        result["error"] = _keep_row_diagnostics(tmp, out / f"{name}.failed", result["error"])
        result["seconds"], result["cpu_seconds"] = round(time.perf_counter() - t0, 3), round(time.thread_time() - c0, 3)
        return result


def _keep_row_diagnostics(tmp: Path, failed: Path, error: str) -> str:
    """Move the diagnostics a failed row's run left (``TMP.failed/``, see
    :mod:`vmesh.io.failed_run`) out of the staging folder to ``OUT/<name>.failed/``;
    returns the error text naming the new place."""
    from .io.atomic import replace_dir
    from .io.failed_run import failed_dir

    left = failed_dir(tmp)
    if not left.is_dir():
        return error
    try:
        replace_dir(left, failed)
    except OSError:
        return error
    return error.replace(str(left), str(failed))


def _commit_row(tmp: Path, final: Path, staging: Path, key: str) -> None:
    """Rename ``tmp`` to ``final`` (one atomic rename). When ``final`` exists: keep it
    if it already holds this row's result (a rescheduled twin finished first), else it
    is an outdated result and is replaced."""
    try:
        os.rename(tmp, final)
        return
    except OSError:
        if not final.exists():
            raise
    prev = read_row(final)
    if prev is not None and prev.get("key") == key and prev.get("status") == "ok":
        shutil.rmtree(tmp, ignore_errors=True)
        return
    old = staging / f"{final.name}.old.{uuid.uuid4().hex[:10]}"
    os.rename(final, old)
    os.rename(tmp, final)
    shutil.rmtree(old, ignore_errors=True)


# ---------------------------------------------------------------------------
# the batch
# ---------------------------------------------------------------------------
@dataclass
class BatchResult:
    """What :func:`run` did: the summary rows (manifest order) and where they are."""

    rows: list
    out: Path
    summary_csv: Path
    summary_parquet: Path | None
    seconds: float
    interrupted: bool = False

    @property
    def n_ok(self) -> int:
        return sum(r["status"] == "ok" for r in self.rows)

    @property
    def n_failed(self) -> int:
        return sum(r["status"] == "failed" for r in self.rows)

    @property
    def n_resumed(self) -> int:
        return sum(bool(r["resumed"]) for r in self.rows)

    def __repr__(self):
        return f"BatchResult({len(self.rows)} rows: {self.n_ok} ok, {self.n_failed} failed, {self.n_resumed} resumed; {self.summary_csv})"


def run(manifest, chain="default", out=None, *, client=None, scheduler: str | None = None, workers: int | None = None, overrides: dict | None = None, retries: int = 1, progress=True, parquet: bool | str = "auto", cache_entries: int = 2, connect_timeout: float = 30.0) -> BatchResult:
    """Mesh every row of a manifest on Dask.

    Parameters
    ----------
    manifest : path, Manifest or list of dict
        A CSV/TOML manifest (:func:`read_manifest`), or rows as dicts with ``surface``,
        optional ``skeleton``/``name`` and ``filter.param`` keys.
    chain : str, path or FilterChain
        The chain every row runs (a preset name such as ``"batch_sweep"``).
    out : path
        Output folder: ``OUT/<name>/`` per row and ``OUT/summary.csv``. Default:
        ``<manifest stem>_out`` beside a manifest file.
    client : distributed.Client, optional
        Run on this client's cluster (it is left open).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) to connect to.
    workers : int, optional
        Without ``client``/``scheduler``: worker processes of the local cluster
        (default: one per CPU core, at most one per row). With ``scheduler``: wait
        until that many workers are connected.
    overrides : dict, optional
        ``{"filter.param": value}`` for every row (rows' own columns win).
    retries : int
        Extra attempts of a failed row (an error or a lost worker) before it is
        reported as failed; a row whose input cannot be read is not retried.
    progress : bool or callable
        Print a progress line/bar to stderr, or call ``progress(done, total, row)`` after
        each row (``row`` is the summary row; ``{"resumed_rows": n}`` once for the rows
        skipped as finished, ``None`` at the end).
    parquet : bool or "auto"
        Also write ``summary.parquet`` ("auto": when pyarrow is installed).
    cache_entries : int
        Prefixes (preprocessed surface + signed distance) each worker keeps.

    Returns
    -------
    BatchResult

    Raises
    ------
    InputError
        A bad manifest, chain or override (before anything runs).
    """
    from .chain import FilterChain

    if not isinstance(manifest, Manifest):
        if isinstance(manifest, (list, tuple)):
            manifest = manifest_from_rows(manifest)
        else:
            manifest = read_manifest(manifest)
    if chain is None:
        chain = manifest.chain or "default"
    chain = chain if isinstance(chain, FilterChain) else FilterChain.load(chain)
    tasks = prepare(manifest, chain, overrides)
    out, created = _output_folder(out, manifest)

    t_start = time.perf_counter()
    rows: dict[str, dict] = {}
    pending = []
    for t in tasks:
        prev = read_row(out / t.name)
        if prev is not None and prev.get("status") == "ok" and prev.get("key") == t.key:
            rows[t.name] = _summary_row(prev, t, attempts=0, resumed=True)
        else:
            pending.append(t)
    say = _progress(progress, len(tasks))
    if rows:
        say({"resumed_rows": len(rows)}, len(rows))
    interrupted = unreachable = False
    stop = _InterruptFlag()
    try:
        if pending:
            with stop:
                _run_pending(pending, rows, out, client, scheduler, workers, retries, cache_entries, connect_timeout, say, lambda: _write_summary(tasks, rows, out, manifest, parquet, final=False), stop)
    except KeyboardInterrupt:
        interrupted = True
        raise
    except _Unreachable:
        # nothing ran: an earlier summary stays as it was, a folder this call made goes
        unreachable = True
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        if not unreachable:
            csv_path, pq_path = _write_summary(tasks, rows, out, manifest, parquet, final=True)
            if not interrupted:
                shutil.rmtree(out / STAGING, ignore_errors=True)  # leftovers of lost workers
        say(None, len(rows))
    return BatchResult([rows.get(t.name) or _pending_row(t) for t in tasks], out, csv_path, pq_path, time.perf_counter() - t_start, interrupted)


def _output_folder(out, manifest: Manifest) -> tuple[Path, bool]:
    """The batch's output folder (default: beside the manifest), made if missing; and
    whether this call made it."""
    if out is None:
        if manifest.path is None:
            raise InputError("give an output folder (out=...)")
        out = manifest.path.resolve().parent / f"{manifest.path.stem}_out"
    out = Path(out).resolve()
    if out.exists() and not out.is_dir():
        raise InputError("output folder is a file", out)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # no permission, a read-only or virtual file system
        raise InputError(f"cannot create the output folder: {exc.strerror or exc}", out) from None
    return out, created


class _Unreachable(VmeshError):
    """The batch's scheduler could not be reached: no row ran."""


class _InterruptFlag:
    """Remembers Ctrl-C while a batch runs (main thread only).

    The KeyboardInterrupt raised by Python's handler can be swallowed when it lands in
    Dask's client machinery; the flag is checked again after every finished row, so the
    batch still stops and writes its summary with the rows left pending.
    """

    def __init__(self):
        self.set = False
        self._old = None

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._old = signal.getsignal(signal.SIGINT)

            def handler(signum, frame):
                self.set = True
                raise KeyboardInterrupt

            signal.signal(signal.SIGINT, handler)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


def _run_pending(pending, rows, out, client, scheduler, workers, retries, cache_entries, connect_timeout, say, checkpoint, stop):
    try:
        from distributed import Client, as_completed
    except ImportError:  # pragma: no cover - dask is a dependency
        raise VmeshError("vmesh batch needs dask[distributed]: python3 -m pip install 'dask[distributed]'") from None

    own_client = own_cluster = None
    if client is None:
        if scheduler:
            try:
                client = own_client = Client(scheduler, timeout=connect_timeout)
            except (OSError, TimeoutError) as exc:
                raise _Unreachable(f"cannot reach the Dask scheduler at {scheduler} ({type(exc).__name__}: {exc})") from None
            if workers:
                client.wait_for_workers(int(workers), timeout=connect_timeout)
        else:
            own_cluster = _local_cluster(workers or max(1, min(os.cpu_count() or 1, len(pending))))
            client = own_client = Client(own_cluster)
    by_name = {t.name: t for t in pending}
    attempts = {t.name: 0 for t in pending}
    futures = {}

    def submit(t):
        attempts[t.name] += 1
        payload = {"name": t.name, "out": str(out), "surface": t.row.surface, "skeleton": t.row.skeleton, "chain": t.chain_toml, "key": t.key, "overrides": t.overrides, "cache_entries": cache_entries}
        f = client.submit(mesh_row, payload, key=f"vmesh-row-{t.name}-{attempts[t.name]}-{uuid.uuid4().hex[:8]}", pure=False)
        futures[f] = t.name
        return f

    try:
        queue = as_completed([submit(t) for t in pending])
        last = time.monotonic()
        for f in queue:
            if stop.set:
                raise KeyboardInterrupt
            name = futures.pop(f)
            try:
                res = f.result()
            except Exception as exc:  # lost worker (KilledWorker), cancelled...
                res = {"name": name, "status": "failed", "error": " ".join(f"{type(exc).__name__}: {exc}".split()), "worker": ""}
            f.release()
            if _retried(res, attempts[name], retries):
                queue.add(submit(by_name[name]))
                continue
            rows[name] = _summary_row(res, by_name[name], attempts=attempts[name], resumed=False)
            say(rows[name], len(rows))
            if stop.set:
                raise KeyboardInterrupt
            if time.monotonic() - last > _SUMMARY_EVERY_S:
                checkpoint()
                last = time.monotonic()
    except BaseException:
        if futures:
            try:
                client.cancel(list(futures))
            except Exception:
                pass
        raise
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()


def _retried(res: dict, attempts: int, retries: int) -> bool:
    """Whether a row's result calls for another attempt: a failure other than an unreadable
    input (``res["retry"]`` False), with fewer than ``1 + retries`` attempts made."""
    return res.get("status") != "ok" and res.get("retry", True) and attempts <= retries


def _local_cluster(n: int):
    """A Dask cluster of ``n`` single-threaded worker processes on this machine."""
    import logging

    from distributed import LocalCluster

    # one thread per process: the mesher's numpy/igl work releases the GIL unevenly,
    # processes scale; each keeps its own prefix cache
    return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)


def _summary_row(res: dict, t: _Task, attempts: int, resumed: bool) -> dict:
    row = {
        "name": t.name,
        "status": res.get("status", "failed"),
        "elements": res.get("elements"),
        "sj_min": _round(res.get("sj_min"), 6),
        "sj_mean": _round(res.get("sj_mean"), 6),
        "seconds": _round(res.get("seconds"), 3),
        "error": res.get("error") or "",
        "attempts": attempts,
        "resumed": resumed,
        "sdf_reused": bool(res.get("sdf_reused")),
        "worker": res.get("worker") or "",
        "cpu_seconds": _round(res.get("cpu_seconds"), 3),
        "surface": t.row.surface,
        "skeleton": t.row.skeleton or "",
    }
    row.update(t.overrides)
    return row


def _round(v, digits):
    return round(float(v), digits) if v is not None else None


def _pending_row(t: _Task) -> dict:
    return _summary_row({"status": "pending", "error": "not run (the batch stopped first)"}, t, attempts=0, resumed=False)


def _write_summary(tasks, rows, out: Path, manifest: Manifest, parquet, final: bool):
    """Write ``summary.csv`` (always) and ``summary.parquet`` (pyarrow) atomically."""
    from .io.atomic import atomic_path

    extra = []
    for t in tasks:
        extra += [k for k in t.overrides if k not in extra]
    columns = list(SUMMARY_COLUMNS) + extra
    table = [rows.get(t.name) or _pending_row(t) for t in tasks]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in table:
        w.writerow({c: _cell(r.get(c)) for c in columns})
    csv_path = out / "summary.csv"
    with atomic_path(csv_path) as tmp:
        tmp.write_text(buf.getvalue())
    pq_path = None
    if parquet and final:
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            if parquet is True:
                print("warning: pyarrow is not installed: summary.parquet not written", file=sys.stderr)
        else:
            cols = {c: [_parquet_cell(r.get(c)) for r in table] for c in columns}
            pq_path = out / "summary.parquet"
            with atomic_path(pq_path) as tmp:
                pq.write_table(pa.table(cols), tmp)
    return csv_path, pq_path


def _cell(v):
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return v


def _parquet_cell(v):
    return json.dumps(v) if isinstance(v, (list, dict)) else v


def read_summary(path) -> list[dict]:
    """Rows of a ``summary.csv`` as dicts of strings."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _progress(progress, total: int):
    """``say(row, done)``: print one line per finished row (or a bar on a terminal)."""
    if callable(progress) and not isinstance(progress, bool):
        return lambda row, done: progress(done, total, row)
    if not progress:
        return lambda row, done: None
    tty = sys.stderr.isatty()
    t0 = time.perf_counter()
    state = {"failed": 0, "resumed": 0, "closed": False}

    def say(row, done):
        if row is None:  # the end
            if tty and not state["closed"]:
                print(file=sys.stderr, flush=True)
            state["closed"] = True
            return
        if "resumed_rows" in row:  # one line for every row finished by an earlier run
            state["resumed"] = row["resumed_rows"]
            print(f"[{done}/{total}] {done} rows finished by an earlier run: skipped", file=sys.stderr, flush=True)
            return
        state["failed"] += row["status"] == "failed"
        state["resumed"] += bool(row["resumed"])
        elapsed = time.perf_counter() - t0
        if tty:
            bar = "#" * int(30 * done / max(total, 1))
            print(f"\r[{bar:<30}] {done}/{total} rows  {state['failed']} failed  {state['resumed']} resumed  {elapsed:6.1f} s", end="", file=sys.stderr, flush=True)
        else:
            what = "resumed" if row["resumed"] else row["status"]
            if row["status"] == "ok":
                detail = f"{row['elements']} elements" + (f", sj_min {row['sj_min']:.3f}" if row["sj_min"] is not None else "") + (f", {row['seconds']:.1f} s" if row["seconds"] is not None else "")
            else:
                detail = row["error"]
            print(f"[{done}/{total}] {what:<7} {row['name']}: {detail}", file=sys.stderr, flush=True)

    return say
