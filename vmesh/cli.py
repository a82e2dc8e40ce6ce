"""The ``vmesh`` command line.

Every failure prints one line, ``vmesh: error: <file or step>: <problem>: <remedy>``, and
exits non-zero (2 for bad input and failed stages, 1 for internal errors, 128 + the signal
for a stopped run); no Python traceback reaches the terminal (``vmesh --debug`` shows it).
A failed run writes no mesh; it leaves its diagnostics in ``OUT.failed/``.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import warnings

from . import __version__
from ._toml import tomllib
from .errors import Stopped, VmeshError, stop_behind

EXIT_USAGE = 2
#: Exit status of an unexpected (internal) error.
EXIT_INTERNAL = 1

#: Sub-commands contributed by other modules: name -> (add_arguments, run)
EXTRA_COMMANDS: dict = {}


def parse_value(text: str):
    """Parse ``--set`` values as TOML (numbers, booleans, lists, strings); bare words stay strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_overrides(items) -> dict:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise VmeshError(f"--set {item!r}: expected filter.param=value")
        out[key.strip()] = parse_value(value.strip())
    return out


def cmd_filters(args) -> int:
    from .registry import filter_list_text, get_filter

    if args.name:
        print(get_filter(args.name).parameter_table())
    else:
        print(filter_list_text())
        print("\n`vmesh filters NAME` prints a filter's parameters.")
    return 0


def cmd_chains(args) -> int:
    from .chain import FilterChain, list_presets

    for name, path in list_presets().items():
        chain = FilterChain.load(path)
        print(f"{name:<20} {chain.description or ''}  [{path}]")
        if args.verbose:
            for i, s in enumerate(chain.steps):
                print(f"    {i + 1}. {s.filter}")
    return 0


def cmd_info(args) -> int:
    from .errors import InputError
    from .io.surface import read_surface

    failed = 0
    for path in args.surface:  # a diagnosis: every file, a bad one does not stop the rest
        try:
            surface = read_surface(path)
        except InputError as exc:
            if args.debug:
                raise
            print(f"vmesh: error: {one_line(str(exc))}", file=sys.stderr)
            failed += 1
            continue
        print(f"{path}")
        print("  " + str(surface.info()).replace("\n", "\n  "))
    return EXIT_USAGE if failed else 0


def cmd_run(args) -> int:
    from .chain import FilterChain

    chain = FilterChain.load(args.chain).with_overrides(parse_overrides(args.set))
    chain.resolved()  # parameter errors before reading any input
    if not args.input:
        raise VmeshError("--input SURFACE is required")
    from .context import Context

    context = Context(inputs={"units": args.units}) if args.units else None  # the input's length unit, stated in report.json
    from .commands.compile import compile_in_background

    compile_in_background()  # a first run: the optimiser's kernels compile on the other core meanwhile
    from . import disk_cache

    # a rerun on the same surface restores repair, caps, decimation and the signed distance from disk
    cache = None
    if disk_cache.enabled():
        from .cache import DiskPrefixCache

        cache = DiskPrefixCache()
    ctx = chain.run(surface=args.input, skeleton=args.skeleton, out_dir=args.out, progress=not args.quiet, context=context, cache=cache)
    if not args.quiet:
        print(ctx.report.summary_table())
        for w in ctx.report.warnings:
            print(f"warning: {w}")
        if args.out:
            print(f"results in {args.out}/")
        else:  # a dry run: the quality is printed, no file is written
            print("no output folder given (-o OUT): nothing was written")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vmesh",
        description="Block-structured hexahedral meshes of blood vessels, built by chains of registered filters.",
    )
    p.add_argument("--version", action="version", version=f"vmesh {__version__}")
    p.add_argument("--debug", action="store_true", help="show the full traceback on errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    s = sub.add_parser("filters", help="list the registered filters, or describe one")
    s.add_argument("name", nargs="?", help="filter name: print its parameters")
    s.set_defaults(func=cmd_filters)

    s = sub.add_parser("chains", help="list the chain presets (filters/*.toml)")
    s.add_argument("-v", "--verbose", action="store_true", help="also list each preset's steps")
    s.set_defaults(func=cmd_chains)

    s = sub.add_parser("info", help="diagnose surface files (triangles, open ends, manifoldness, orientation)")
    s.add_argument("surface", nargs="+")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("run", help="run a filter chain on a surface")
    s.add_argument("chain", help="chain file (.toml) or preset name, e.g. 'default'")
    s.add_argument("-i", "--input", required=False, help="input surface (stl, obj, ply, vtp, vtk, vtu, off)")
    s.add_argument("-s", "--skeleton", help="centerline file (json, swc, vtp, vtk, csv, ply); extracted when absent")
    s.add_argument("--set", action="append", metavar="FILTER.PARAM=VALUE", help="override a parameter (repeatable)")
    s.add_argument("-o", "--out", help="output folder (without it the chain runs and prints its quality, but writes nothing)")
    s.add_argument("--units", choices=("mm", "cm", "m"), help="length unit of the input (default: m if the surface's diagonal is below 2, else mm; stated in report.json)")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    s.set_defaults(func=cmd_run)

    for name, (add_arguments, func, help_text) in EXTRA_COMMANDS.items():
        s = sub.add_parser(name, help=help_text)
        add_arguments(s)
        s.set_defaults(func=func)
    return p


def _unrecognized(args, extra: list[str]) -> str:
    """argparse's message for stray arguments, with the likely cause: ``--set a.b 3`` (a space for ``=``)."""
    msg = f"unrecognized arguments: {' '.join(extra)}"
    loose = [s for s in (getattr(args, "set", None) or []) if "=" not in s]
    if loose:
        msg += f" (--set takes FILTER.PARAM=VALUE in one word: --set {loose[0]}={extra[0]})"
    return msg


def main(argv=None) -> int:
    _load_extra_commands()
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        parser.error(_unrecognized(args, extra))
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    restore = _stop_on_signals()
    sys.unraisablehook = _unraisable_hook(sys.unraisablehook, args.debug)
    try:
        with warnings.catch_warnings():
            if not args.debug and not sys.warnoptions:
                warnings.simplefilter("ignore")  # library warnings are no message for a user
            return int(args.func(args) or 0)
    except VmeshError as exc:
        if args.debug:
            raise
        print(f"vmesh: error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_USAGE
    except (KeyboardInterrupt, Stopped) as exc:
        if args.debug:
            raise
        return _report_stop(exc)
    except BrokenPipeError:  # output piped into `head` and the like
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as exc:  # a bug: one line for the user, the traceback in a log file
        stop = stop_behind(exc)
        if stop is not None and not args.debug:
            return _report_stop(stop)
        if args.debug:
            raise
        log = _write_traceback(exc)
        where = f" (traceback in {log})" if log else ""
        print(f"vmesh: error: '{args.command}' stopped on an internal error, a bug in vmesh: please report it{where}; "
              f"vmesh --debug {args.command} ... shows the traceback", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        restore()


def _unraisable_hook(default, debug: bool):
    """A :data:`sys.unraisablehook` for the command line.

    A signal whose handler runs inside a finaliser (``__del__``, e.g. llvmlite's while numba
    compiles) raises :class:`Stopped` (or KeyboardInterrupt) where Python can only print it
    ("Exception ignored in ...", a traceback) and go on: the stop would be lost and the run
    finish. The signal is sent again, so that it stops the run at the next step as usual.
    Other errors in finalisers are no message for a user (``--debug`` prints them)."""

    def hook(unraisable):
        exc = unraisable.exc_value
        if isinstance(exc, Stopped):
            os.kill(os.getpid(), exc.signal_number)
        elif isinstance(exc, KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
        elif debug:
            default(unraisable)

    return hook


def one_line(text: str) -> str:
    return " ".join(text.split())


def _report_stop(exc) -> int:
    """Print the one line for a stopped run; its exit status (128 + the signal)."""
    print(f"vmesh: error: {one_line(getattr(exc, 'message', None) or _stopped_text(exc))}", file=sys.stderr)
    return 128 + (exc.signal_number if isinstance(exc, Stopped) else signal.SIGINT)


def _stopped_text(exc) -> str:
    return f"stopped by {exc.signal_name}" if isinstance(exc, Stopped) else "interrupted (SIGINT)"


def _stop_on_signals():
    """Turn SIGTERM and SIGHUP into :class:`Stopped` (as SIGINT is KeyboardInterrupt), so
    that a stopped run removes its staging folder and leaves OUT.failed/; returns a
    function restoring the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {}

    def stop(number, frame):
        raise Stopped(signal.Signals(number).name, number)

    for sig in (signal.SIGTERM, signal.SIGHUP):
        try:
            previous[sig] = signal.signal(sig, stop)
        except (ValueError, OSError):
            pass

    def restore():
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def _write_traceback(exc: BaseException) -> str | None:
    """Write the traceback of an unexpected error to a log file; its path, or None."""
    import tempfile
    import traceback

    try:
        fd, path = tempfile.mkstemp(prefix="vmesh-error-", suffix=".log")
        with os.fdopen(fd, "w") as f:
            f.write(f"vmesh {__version__}: {' '.join(sys.argv)}\n\n")
            f.write("".join(traceback.format_exception(type(exc), exc, exc.__traceback__)))
        return path
    except OSError:
        return None


def _load_extra_commands():
    """Import modules that add sub-commands (skeleton, render, export, batch)."""
    import importlib

    for mod in ("vmesh.commands",):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise


if __name__ == "__main__":
    sys.exit(main())
