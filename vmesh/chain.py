"""Filter chains: ordered (filter, parameters) steps, saved and loaded as TOML."""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__
from ._toml import tomllib
from .context import Context, StepReport
from .errors import ChainError, InputError, ParameterError, Stopped, VmeshError, stop_behind
from .io.atomic import replace_dir
from .io.failed_run import OWNER_FILE, failed_dir, keep_failed, mark_owner, remove_failed, remove_stale_stages, write_diagnostics
from .monitor import ResourceMonitor
from .preload import LATER_STEPS
from .registry import filter_list, get_filter, suggest

#: Folders searched for chain presets named without a path (``vmesh run default``).
PRESET_DIRS = [
    Path(__file__).resolve().parent.parent / "filters",  # a source checkout
    Path(__file__).resolve().parent / "presets",  # an installed package
]


def preset_dirs() -> list[Path]:
    extra = [Path(p) for p in os.environ.get("VMESH_CHAIN_PATH", "").split(os.pathsep) if p]
    return [d for d in (*extra, *PRESET_DIRS) if d.is_dir()]


def list_presets() -> dict[str, Path]:
    """Chain presets by name (first found wins)."""
    out: dict[str, Path] = {}
    for d in preset_dirs():
        for p in sorted(d.glob("*.toml")):
            out.setdefault(p.stem, p)
    return out


def find_chain_file(name_or_path: str | Path) -> Path:
    """Resolve a chain file path or a preset name to a file."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.suffix == "" and p.parent == Path("."):
        presets = list_presets()
        if p.name in presets:
            return presets[p.name]
        raise InputError("no such chain file or preset" + suggest(p.name, presets) + f" (presets: {', '.join(presets)})", p)
    raise InputError("chain file not found", p)


@dataclass
class Step:
    """One step of a chain: a filter name and its (possibly partial) parameters."""

    filter: str
    params: dict = field(default_factory=dict)

    def resolved(self) -> "Step":
        return Step(self.filter, get_filter(self.filter).resolve(self.params))


class FilterChain:
    """An ordered list of filters with parameters.

    Examples
    --------
    >>> chain = FilterChain(["repair_surface", ("decimate_surface", {"target_faces": 5000})])
    >>> chain.append("build_sdf", source="coarse")          # doctest: +SKIP
    >>> ctx = chain.run(surface="vessel.stl", out_dir="out")  # doctest: +SKIP
    >>> chain.save("my_chain.toml")                          # doctest: +SKIP
    """

    def __init__(self, steps=(), name: str = "", description: str = ""):
        self.name = name
        self.description = description
        self.steps: list[Step] = []
        for s in steps:
            self._add(s)

    # -- building ------------------------------------------------------
    def _add(self, s):
        if isinstance(s, Step):
            step = Step(s.filter, dict(s.params))
        elif isinstance(s, str):
            step = Step(s, {})
        elif isinstance(s, dict):
            step = Step(s["filter"], dict(s.get("params", {})))
        else:
            fname, params = s
            step = Step(fname, dict(params or {}))
        f = get_filter(step.filter)  # unknown names fail here, with a suggestion
        for key in step.params:  # so do unknown parameters: a chain file names its line
            f.parameter(key)
        self.steps.append(step)

    def append(self, filter_name: str, params: dict | None = None, /, **kw) -> "FilterChain":
        """Add a step; returns the chain so calls can be chained.

        Parameters go as keywords (``append("decimate_surface", target_faces=5000)``) or as
        one dict. A keyword ``params`` is the filter's own parameter where it has one
        (``append("meshlab_filter", name="...", params={...})``), else the dict.
        """
        if "params" in kw and "params" not in get_filter(filter_name).parameter_names:
            params = {**(params or {}), **kw.pop("params")}
        self._add(Step(filter_name, {**(params or {}), **kw}))
        return self

    def __len__(self):
        return len(self.steps)

    def __iter__(self):
        return iter(self.steps)

    def __repr__(self):
        lines = [f"FilterChain({self.name!r}, {len(self)} steps)"]
        lines += [f"  {i + 1}. {s.filter} {s.params if s.params else ''}".rstrip() for i, s in enumerate(self.steps)]
        return "\n".join(lines)

    # -- parameters ----------------------------------------------------
    def resolved(self) -> "FilterChain":
        """A copy with every parameter validated and every default filled in."""
        errors = []
        steps = []
        for i, s in enumerate(self.steps):
            try:
                steps.append(s.resolved())
            except ParameterError as exc:
                errors.append(f"step {i + 1}: {exc}")
        if errors:
            raise ParameterError("; ".join(errors))
        return FilterChain(steps, name=self.name, description=self.description)

    def with_overrides(self, overrides: dict) -> "FilterChain":
        """A copy with ``{"filter.param": value}`` applied to every step of that filter."""
        chain = FilterChain(self.steps, self.name, self.description)
        for key, value in overrides.items():
            fname, _, pname = key.partition(".")
            if not pname:
                raise ParameterError(f"override '{key}' must look like filter.param=value")
            matches = [s for s in chain.steps if s.filter == fname]
            if not matches:
                known = fname in filter_list()  # a filter the chain lacks: say how to add it
                raise ParameterError(
                    f"override '{key}': filter '{fname}' is not in this chain"
                    + (f" (--set changes a step the chain has; add a [[step]] filter = \"{fname}\" to a copy of the"
                       " chain's TOML file: docs/chains.md)" if known else suggest(fname, filter_list()))
                )
            # unknown parameter: suggestion; a value its parameter refuses fails here, not at run
            get_filter(fname).parameter(pname).validate(value, f"filter '{fname}'")
            for s in matches:
                s.params[pname] = value
        return chain

    def check_layers(self, available) -> None:
        """Fail before running when a step needs a layer nothing provides."""
        have = set(available)
        for i, s in enumerate(self.steps):
            f = get_filter(s.filter)
            missing = [layer for layer in f.reads if layer not in have]
            if missing:
                raise ChainError(
                    f"step {i + 1} '{s.filter}' needs the {', '.join(missing)} layer, which neither an input "
                    f"nor an earlier step provides"
                    + (" (give --skeleton FILE or add extract_skeleton)" if "skeleton" in missing else "")
                )
            have.update(layer for layer in f.writes if layer not in f.updates or layer in have)

    # -- files -----------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"chain": {"name": self.name, "description": self.description, "vmesh_version": __version__}}
        # a [step.params] table only where there are parameters, so tomli_w writes [[step]] tables
        d["step"] = [{"filter": s.filter, **({"params": _toml_clean(s.params)} if _toml_clean(s.params) else {})} for s in self.steps]
        return d

    def to_toml(self, header: str = "") -> str:
        """The chain as TOML: a ``[chain]`` table, then one ``[[step]]`` table per step with
        its parameters in a ``[step.params]`` table (the layout of the presets in filters/)."""
        import tomli_w

        d = self.to_dict()
        parts = [tomli_w.dumps({"chain": d["chain"]})]
        for step, original in zip(d["step"], self.steps):
            text = f"[[step]]\nfilter = {tomli_w.dumps({'f': step['filter']}).split('=', 1)[1].strip()}\n"
            if step.get("params"):
                text += "\n" + tomli_w.dumps({"step": {"params": step["params"]}})
            # TOML has no null: parameters left automatic are listed as comments
            unset = [k for k, v in original.params.items() if v is None]
            if unset:
                text += ("" if step.get("params") else "\n[step.params]\n") + "".join(f"# {k} = \"auto\"  (not set: its default)\n" for k in unset)
            parts.append(text)
        return (header + "\n" if header else "") + "\n".join(parts)

    def save(self, path) -> Path:
        from .io.atomic import write_text_atomic

        return write_text_atomic(path, self.to_toml("# vmesh filter chain (load with vmesh.FilterChain.load)"))

    @classmethod
    def from_dict(cls, data: dict, source: str = "") -> "FilterChain":
        meta = data.get("chain", {})
        raw = data.get("step", [])
        if not isinstance(raw, list) or not raw:
            raise InputError("chain has no [[step]] entries", source or None)
        steps = []
        for i, s in enumerate(raw):
            if not isinstance(s, dict) or "filter" not in s:
                raise InputError(f"step {i + 1} has no 'filter' key", source or None)
            extra = set(s) - {"filter", "params"}
            if extra:
                raise InputError(f"step {i + 1}: unknown key(s) {', '.join(sorted(extra))} (use a [step.params] table)", source or None)
            if not isinstance(s.get("params", {}), dict):
                raise InputError(f"step {i + 1} ({s['filter']}): params must be a table of name = value", source or None)
            steps.append(Step(s["filter"], dict(s.get("params", {}))))
        chain = cls(name=meta.get("name", ""), description=meta.get("description", ""))
        for i, step in enumerate(steps):
            try:
                chain._add(step)
            except ParameterError as exc:
                raise InputError(f"step {i + 1}: {exc}", source or None) from None
        return chain

    @classmethod
    def from_toml(cls, text: str, source: str = "") -> "FilterChain":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"not valid TOML ({exc})", source or None) from None
        return cls.from_dict(data, source)

    @classmethod
    def load(cls, name_or_path) -> "FilterChain":
        """Load a chain from a TOML file, or a preset by name (``"default"``)."""
        path = find_chain_file(name_or_path)
        if path.stat().st_size == 0:
            raise InputError("file is empty", path)
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            raise InputError("not a text (TOML) file", path) from None
        chain = cls.from_toml(text, str(path))
        chain.name = chain.name or path.stem
        return chain

    # -- running ---------------------------------------------------------
    def run(self, surface=None, skeleton=None, out_dir=None, progress: bool | object = False, context: Context | None = None, cache=None) -> Context:
        """Run every step in order and return the context.

        Parameters
        ----------
        surface : path or SurfaceMesh, optional
            The input surface (the *fine* surface layer).
        skeleton : path or Skeleton, optional
            A centerline; without it the chain must extract one.
        out_dir : path, optional
            Output folder. Files are staged in a hidden sibling folder and moved in only
            when the whole chain succeeds, together with ``chain.toml`` (the chain as run,
            every parameter resolved) and ``report.json``.
        progress : bool or callable
            Print per-filter progress to stderr (or call ``progress(event, **info)``).
        context : Context, optional
            Run in this context (its layers count as inputs).
        cache : vmesh.cache.PrefixCache, optional
            Reuse the steps through ``build_sdf`` from earlier runs on the same input
            with the same parameters (sets ``context.cache``).
        """
        resolved = self.resolved()  # every parameter checked before anything runs
        if out_dir is not None:
            out_dir = Path(out_dir)
            check_out_dir(out_dir)
        ctx = context or Context()
        if cache is not None:
            ctx.cache = cache
        notes = _read_inputs(ctx, surface, skeleton)
        resolved.check_layers([layer for layer in ("surface", "coarse_surface", "caps", "sdf", "skeleton", "blocks", "mesh") if ctx.has(layer)])

        say = _printer(progress)
        if progress:
            ctx.progress = lambda frac, msg="": say("tick", fraction=frac, message=msg)
        for note in notes:
            ctx.warn(note)
        stage = _open_stage(ctx, out_dir) if out_dir is not None else None
        t0 = time.perf_counter()
        current = None  # (step number, filter name) while a step runs
        try:
            n = len(resolved.steps)
            # a prefix cache (batches) restores the steps up to the signed distance when it can
            plan = ctx.cache.plan(ctx, resolved.steps) if ctx.cache is not None else None
            for i, step in enumerate(resolved.steps):
                if plan is not None and i < plan.skip:
                    continue
                current = (i + 1, step.filter)
                say("start", index=i + 1, total=n, name=step.filter)
                later = LATER_STEPS.set(tuple(resolved.steps[i + 1 :]))  # what a waiting step may prepare (vmesh.preload)
                try:
                    _run_step(ctx, i + 1, step, say if progress is True else None, failed_dir(out_dir) / "failure.log" if stage is not None else None)
                finally:
                    LATER_STEPS.reset(later)
                current = None
                say("end", index=i + 1, total=n, name=step.filter, step=ctx._step)
                ctx._step = None
                if plan is not None and i + 1 == plan.store_after:
                    plan.store(ctx)
            ctx.report.total_s = time.perf_counter() - t0
            if stage is not None:
                _publish_stage(ctx, resolved, stage, out_dir)
        except BaseException as exc:
            if stage is not None and stage.exists():
                raise _keep_failed_run(exc, ctx, stage, out_dir, resolved, current) from exc.__cause__
            raise
        finally:
            ctx._step = None
            if stage is not None and stage.exists():
                shutil.rmtree(stage, ignore_errors=True)
        return ctx


def _read_inputs(ctx: Context, surface, skeleton) -> list[str]:
    """Put the input surface and skeleton (objects or paths) into the context; returns
    what reading them changed (a volume mesh, stray cells...)."""
    from .io.skeleton import read_skeleton
    from .io.surface import read_surface
    from .skeleton import Skeleton
    from .surface import SurfaceMesh

    notes: list[str] = []
    if surface is not None:
        if isinstance(surface, SurfaceMesh):
            ctx.surface = surface
        else:
            ctx.inputs["surface"] = str(surface)
            ctx.surface = read_surface(surface, notes)
    if skeleton is not None:
        if isinstance(skeleton, Skeleton):
            ctx.skeleton = skeleton
        else:
            ctx.inputs["skeleton"] = str(skeleton)
            ctx.skeleton = read_skeleton(skeleton)
    return notes


def _open_stage(ctx: Context, out_dir: Path) -> Path:
    """The hidden staging folder beside ``out_dir`` that the steps write into."""
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_stages(out_dir)  # left by killed runs
        stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))
    except OSError as exc:  # a read-only or virtual file system, where even root cannot write
        raise InputError(f"cannot create the output folder: {exc.strerror or exc}", out_dir) from None
    mark_owner(stage)
    ctx.stage_dir, ctx.out_dir = stage, out_dir
    return stage


def _run_step(ctx: Context, number: int, step: Step, say, log: Path | None) -> None:
    """Run one step under the resource monitor and record its report in ``ctx._step``.

    Errors become one-line chain errors naming the step; an internal error points to
    ``log`` (the traceback kept in OUT.failed/failure.log) when there is an output folder.
    """
    f = get_filter(step.filter)
    ctx._step = StepReport(step.filter, step.params)
    with ResourceMonitor() as mon, _Heartbeat(say, step.filter):
        try:
            f.function(ctx, **step.params)
        except Exception as exc:
            # a signal inside a C extension's import comes back as its error (a filter may
            # also turn that error into its own): still a stop
            stop = stop_behind(exc)
            if stop is not None:
                raise stop from None
            if isinstance(exc, VmeshError):
                raise _with_message(exc, f"step {number} '{step.filter}': {exc}") from exc
            if isinstance(exc, MemoryError):
                raise ChainError(
                    f"step {number} '{step.filter}' ran out of memory: decimate the surface "
                    f"(decimate_surface.target_faces) or mesh a smaller part"
                ) from None
            raise ChainError(internal_error_text(number, step.filter, log)) from exc
    ctx._step.seconds = mon.seconds
    ctx._step.cpu_seconds = mon.cpu_seconds
    ctx._step.peak_memory_mb = mon.peak_mb
    ctx._step.extra_memory_mb = mon.extra_mb
    ctx.report.steps.append(ctx._step)


def _publish_stage(ctx: Context, resolved: "FilterChain", stage: Path, out_dir: Path) -> None:
    """Write ``chain.toml`` and ``report.json`` and move the staged folder to ``out_dir``."""
    header = "# vmesh filter chain, exactly as run (every parameter resolved)"
    if ctx.inputs:
        header += "\n# inputs: " + ", ".join(f"{k}={v}" for k, v in ctx.inputs.items())
    (stage / "chain.toml").write_text(resolved.to_toml(header))
    report = ctx.report.to_dict()
    report["inputs"] = dict(ctx.inputs)
    report["chain"] = resolved.name
    (stage / "report.json").write_text(json.dumps(report, indent=2))
    (stage / OWNER_FILE).unlink(missing_ok=True)
    replace_dir(stage, out_dir)  # the whole folder: no earlier run's files stay beside the new ones
    ctx.stage_dir = None
    remove_failed(out_dir)


#: What to try when a filter stops on an internal error, beyond its own parameters.
INTERNAL_ERROR_REMEDIES = {
    "extract_skeleton": "give a centerline with --skeleton",
    "read_skeleton": "check the centerline file (vmesh skeleton FILE)",
    "repair_surface": "repair the surface in MeshLab or another mesh editor",
    "cap_open_ends": "cap the surface in MeshLab or another mesh editor, or try cap_open_ends.method",
}


def internal_error_text(number: int, filter_name: str, log: str | Path | None = None) -> str:
    """The one line for an unexpected error inside a filter (no Python text: the traceback
    goes to the failure log, or is shown by ``vmesh --debug``)."""
    remedy = INTERNAL_ERROR_REMEDIES.get(filter_name)
    return (
        f"step {number} '{filter_name}' stopped on an internal error (a bug in vmesh, please report it"
        + (f" with {log}" if log else "; vmesh --debug shows the traceback")
        + f"): try other parameters (vmesh filters {filter_name})"
        + (f" or {remedy}" if remedy else "")
    )


def _with_message(exc: BaseException, message: str) -> BaseException:
    """An exception of the same kind as ``exc`` with a new message (a ChainError if its
    class takes other arguments)."""
    try:
        new = type(exc)(message)
    except Exception:
        new = ChainError(message)
    return new


def _keep_failed_run(exc: BaseException, ctx, stage: Path, out_dir: Path, chain: "FilterChain", current) -> BaseException:
    """Turn the staging folder of a failed or stopped run into ``OUT.failed/`` (log,
    report so far, skeleton, what the filter wrote) and return the exception to raise,
    its message naming that folder."""
    failed = failed_dir(out_dir)
    step = current[1] if current else None
    if isinstance(exc, VmeshError):
        message = str(exc)
    elif isinstance(exc, (KeyboardInterrupt, Stopped)):
        what = exc.signal_name if isinstance(exc, Stopped) else "SIGINT"
        message = f"stopped by {what}" + (f" during step {current[0]} '{current[1]}'" if current else "")
    else:  # raised outside a filter (writing the results): a bug, the traceback goes to the log
        message = f"the run stopped on an internal error after its last step (a bug in vmesh, please report it with {failed / 'failure.log'})"
    message = message.replace(str(stage), str(failed))
    try:
        (stage / "chain.toml").write_text(chain.to_toml("# vmesh filter chain of a failed run (every parameter resolved)"))
    except OSError:
        pass
    write_diagnostics(stage, ctx, message, step, exc.__cause__ if isinstance(exc, ChainError) and exc.__cause__ else exc)
    try:
        keep_failed(stage, out_dir)
        kept = True
    except OSError:
        kept = False
    ctx.stage_dir = None
    if kept:
        message += f"; what the run reached (log, report, skeleton) is in {failed}/"
    if isinstance(exc, (KeyboardInterrupt, Stopped)):
        exc.failed_dir = failed if kept else None
        exc.message = message
        return exc
    new = _with_message(exc, message) if isinstance(exc, VmeshError) else ChainError(message)
    new.failed_dir = failed if kept else None
    return new


#: Seconds without progress after which a running step says it is still running.
_HEARTBEAT_S = 30.0


class _Heartbeat:
    """While a step runs, say every ``interval`` seconds that it is still running when it
    reported no progress of its own meanwhile (so a long stage never looks hung)."""

    def __init__(self, say, name: str, interval: float | None = None):
        self.say, self.name, self.interval = say, name, interval or _HEARTBEAT_S
        self._stop = threading.Event()

    def _beat(self):
        t0 = time.perf_counter()
        while not self._stop.wait(self.interval):
            self.say("alive", name=self.name, seconds=time.perf_counter() - t0)

    def __enter__(self):
        if self.say is not None:
            self._thread = threading.Thread(target=self._beat, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        return False


#: Files that mark a folder as a finished vmesh run (written last, by every run).
RUN_FOLDER_MARKERS = ("report.json", "chain.toml")


def check_out_dir(out_dir: Path) -> None:
    """Refuse an output folder that a run must not replace: a file, or a folder with other
    content than an earlier vmesh run (whose files would otherwise mix with the new ones)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a folder (the output must be a folder)", out_dir)
    if out_dir.is_dir() and any(out_dir.iterdir()) and not any((out_dir / m).is_file() for m in RUN_FOLDER_MARKERS):
        raise InputError("is not empty and not a vmesh run folder (no report.json): give a new or empty folder", out_dir)
    for parent in out_dir.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"{parent} is not a folder", out_dir)
            if not os.access(parent, os.W_OK | os.X_OK):
                raise InputError(f"cannot write in {parent} (no permission)", out_dir)
            break


def _toml_clean(params: dict) -> dict:
    """TOML has no null: unset (automatic) parameters are left out."""
    return {k: v for k, v in params.items() if v is not None}


def _printer(progress):
    if callable(progress) and not isinstance(progress, bool):
        return progress
    if not progress:
        return lambda event, **info: None
    tty = sys.stderr.isatty()
    state = {"last": -1.0}

    def say(event, **info):
        if event == "start":
            state["last"], state["ticked"] = -1.0, False
            print(f"[{info['index']}/{info['total']}] {info['name']} ...", file=sys.stderr, flush=True)
        elif event == "tick":
            state["tick_t"], state["ticked"] = time.perf_counter(), True
            frac = info["fraction"]
            if tty:
                bar = "#" * int(30 * frac)
                print(f"\r    [{bar:<30}] {100 * frac:5.1f}% {info['message'][:40]:<40}", end="", file=sys.stderr, flush=True)
                if frac >= 1:
                    print(file=sys.stderr)
            elif frac - state["last"] >= 0.25 or frac >= 1 > state["last"]:
                state["last"] = frac
                print(f"    {100 * frac:5.1f}% {info['message']}", file=sys.stderr, flush=True)
        elif event == "alive":
            if time.perf_counter() - state.get("tick_t", 0.0) >= 0.9 * _HEARTBEAT_S:
                print(("\n" if tty and state.get("ticked") else "") + f"    ... {info['name']} still running ({info['seconds']:.0f} s)", file=sys.stderr, flush=True)
        elif event == "end":
            s = info["step"]
            counts = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in s.counts.items())
            print(f"      done in {s.seconds:.2f} s, peak {s.peak_memory_mb:.0f} MB" + (f"  ({counts})" if counts else ""), file=sys.stderr, flush=True)

    return say
