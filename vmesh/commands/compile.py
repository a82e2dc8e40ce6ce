"""``vmesh compile``: compile and cache the numba kernels once, e.g. right after installing.

vmesh's geometry kernels are numba functions compiled on first use and cached on disk
(``cache=True``), keyed on the content of the kernel sources, not on their path
(:mod:`vmesh.numba_cache`: ``~/.cache/vmesh/numba``, or ``$NUMBA_CACHE_DIR/vmesh``), so
another clone, worktree or virtual environment of the same sources reuses them. The first
``vmesh run`` of a new version of the sources on a machine therefore spends ~40 s compiling.
pip has no post-install hook, so ``vmesh compile`` is that step: it runs the default chain, without
writing files, on a small generated vessel (a capped tube) sized so that both the serial
and the parallel variants of the kernels run (the surface queries' parallel variants, which
the tube's chain does not reach, by a query of their own), and every later run loads them
from the cache.

Examples
--------
::

    pip install vmesh && vmesh compile
    NUMBA_CACHE_DIR=/shared/cache vmesh compile      # a cache shared by the users of one machine
"""

from __future__ import annotations

import time

import numpy as np

from ..cli import EXTRA_COMMANDS

HELP = "compile and cache the numba kernels of the default chain (run once after installing)"


def add_arguments(p) -> None:
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.add_argument("--optimiser", action="store_true", help="only the mesh optimiser's kernels and the parallel surface queries (what a first run compiles in the background)")


def optimiser_cached() -> bool:
    """Whether the optimiser's serial sweep (its largest kernel) is in the kernel cache."""
    from .. import numba_cache

    module = numba_cache.PACKAGE / "geometry" / "optimize" / "kernels.py"
    return any(numba_cache.cache_folder(str(module)).glob("kernels.sweep_colour_serial-*.nbi"))


def _claim_background_compile(seconds: float = 300.0) -> bool:
    """One background compile at a time per machine and sources: a lock file in the optimiser's
    cache folder, taken when absent or older than ``seconds`` (a child that died)."""
    import os

    from .. import numba_cache

    folder = numba_cache.cache_folder(str(numba_cache.PACKAGE / "geometry" / "optimize" / "kernels.py"))
    lock = folder / "background-compile.lock"
    try:
        if lock.exists() and time.time() - lock.stat().st_mtime < seconds:
            return False
        folder.mkdir(parents=True, exist_ok=True)
        lock.unlink(missing_ok=True)
        os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        return True
    except OSError:  # another process took it first, or no writable folder
        return False


def compile_in_background():
    """When the optimiser's kernels are not cached yet (a first run of these sources), compile
    them in a child process (``vmesh compile --optimiser``) while this one runs the chain's
    earlier steps and compiles their kernels: the optimiser's ~17 s CPU of compiling run on
    the other core, and the optimiser loads them from the cache when it starts. Should it
    start first, it compiles them itself, as without the child. ``VMESH_BACKGROUND_COMPILE=0``
    turns it off. Returns the child process, or None."""
    import os
    import subprocess
    import sys

    if os.environ.get("VMESH_BACKGROUND_COMPILE", "1") == "0" or os.environ.get("VMESH_NUMBA_CACHE") == "path":
        return None
    try:
        if optimiser_cached() or not _claim_background_compile():
            return None
        return subprocess.Popen([sys.executable, "-m", "vmesh", "compile", "--optimiser", "-q"], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError:
        return None


def capped_tube(radius: float = 2.0, length: float = 24.0, around: int = 64, along: int = 96):
    """A closed, outward-oriented triangle surface of a straight tube with flat caps, and its
    centerline (as :class:`~vmesh.surface.SurfaceMesh` and :class:`~vmesh.skeleton.Skeleton`)."""
    from ..skeleton import Skeleton
    from ..surface import SurfaceMesh

    t = 2 * np.pi * np.arange(around) / around
    z = np.linspace(0.0, length, along)
    ring = np.stack([radius * np.cos(t), radius * np.sin(t)], axis=1)
    wall = np.concatenate([np.column_stack([ring, np.full(around, zk)]) for zk in z])
    vertices = np.vstack([wall, [[0.0, 0.0, 0.0], [0.0, 0.0, length]]])
    i, k = np.meshgrid(np.arange(around), np.arange(along - 1), indexing="ij")
    a = k * around + i
    b = k * around + (i + 1) % around
    quads_lo, quads_hi = np.stack([a, b, b + around], -1).reshape(-1, 3), np.stack([a, b + around, a + around], -1).reshape(-1, 3)
    bottom, top = len(wall), len(wall) + 1
    j = np.arange(around)
    cap_lo = np.stack([np.full(around, bottom), (j + 1) % around, j], -1)  # normal -z
    last = (along - 1) * around
    cap_hi = np.stack([np.full(around, top), last + j, last + (j + 1) % around], -1)  # normal +z
    faces = np.vstack([quads_lo, quads_hi, cap_lo, cap_hi]).astype(np.int64)
    n_nodes = 13
    points = np.column_stack([np.zeros(n_nodes), np.zeros(n_nodes), np.linspace(0.0, length, n_nodes)])
    edges = np.column_stack([np.arange(n_nodes - 1), np.arange(1, n_nodes)])
    tags = [{"vessel"} for _ in range(n_nodes)]
    tags[0].add("inlet")
    tags[-1].add("outlet")
    skeleton = Skeleton(points=points, radii=np.full(n_nodes, radius), edges=edges, node_tags=tags, name="compile_tube")
    return SurfaceMesh(vertices, faces, name="compile_tube"), skeleton


def compile_kernels(progress: bool = False) -> tuple[float, int]:
    """Run the default chain on :func:`capped_tube` (into a scratch folder, removed); returns the seconds and
    the number of compiled kernel specialisations now held by the geometry modules.
    ``progress``: say on stderr what is being compiled (each step of the chain as it runs)."""
    import sys
    import tempfile
    import warnings
    from pathlib import Path

    from ..chain import FilterChain

    def say(message):
        if progress:
            print(f"vmesh compile: {message}", file=sys.stderr, flush=True)

    say("compiling the numba kernels once, through the default chain on a small tube (about 30-60 s on 2 cores; later runs load them)")
    surface, skeleton = capped_tube()
    t0 = time.perf_counter()
    # the optimiser's kernels (~40 % of the compiling) on the other core meanwhile, as in a
    # first ``vmesh run``: the whole compile then takes about as long as the chain's own share
    child = compile_in_background()
    with warnings.catch_warnings(), tempfile.TemporaryDirectory(prefix="vmesh_compile_") as scratch:
        warnings.simplefilter("ignore")
        # into a scratch folder: the writers run (and compile) as in a user's run, and say nothing
        FilterChain.load("default").run(surface=surface, skeleton=skeleton, out_dir=Path(scratch) / "tube",
                                        progress=_step_names if progress else False)
    if child is not None:
        say("waiting for the optimiser's kernels (compiled in a second process)")
        child.wait()  # its kernels are in the cache now: warm_up below loads them
    from ..geometry.optimize.kernels import warm_up

    say("loading the optimiser's and the surface queries' parallel variants")
    warm_up()  # the optimiser's parallel variants (the tube's colours are all small)
    _warm_parallel_queries(surface)  # loaded: the child ran them after the optimiser's
    from ..geometry.handles import warm_up as warm_handles

    warm_handles()  # repair_surface's loop search, run only on vessels with loops
    return time.perf_counter() - t0, _compiled_count()


def _step_names(event, **info) -> None:
    """The chain's progress as ``vmesh compile`` shows it: each step's name as it starts, and
    the chain's "still running" notes (no counts or warnings: the tube is not the user's)."""
    import sys

    if event == "start":
        print(f"  [{info['index']}/{info['total']}] {info['name']}", file=sys.stderr, flush=True)
    elif event == "alive":
        print(f"      ... {info['name']} still compiling ({info['seconds']:.0f} s)", file=sys.stderr, flush=True)


def _warm_parallel_queries(surface) -> None:
    """The surface queries' parallel variants the tube's chain leaves out: its sign tests and
    ray casts stay under ``bvh.PARALLEL_MIN`` points (serial kernels), a real vessel's do not
    (the first ICA run after ``vmesh compile`` compiled ``_signs_kernel`` and
    ``_line_kernel``, ~1.7 s CPU). Through the same public queries the chain makes, so with
    its argument types. The background child (``--optimiser``) runs it after the
    optimiser's kernels, so a first ``vmesh run`` gets them on the other core too."""
    from ..geometry.bvh import PARALLEL_MIN
    from ..geometry.sdf import SignedDistance

    sdf = SignedDistance.from_surface(surface)
    lo, hi = sdf.bounds
    points = lo + (hi - lo) * np.random.default_rng(0).random((PARALLEL_MIN, 3))
    sdf.distance(points)
    sdf.intersect_lines(points, np.tile([1.0, 0.0, 0.0], (PARALLEL_MIN, 1)), 1.0)


def _compiled_count() -> int:
    import sys

    from numba.core.registry import CPUDispatcher

    count = 0
    for name, module in list(sys.modules.items()):
        if name.startswith("vmesh.") and module is not None:
            count += sum(len(v.overloads) for v in vars(module).values() if isinstance(v, CPUDispatcher))
    return count


def run(args) -> int:
    if args.optimiser:
        from ..geometry.optimize.kernels import warm_up

        t0 = time.perf_counter()
        warm_up()
        # then the parallel surface queries: the other process has cached the BVH's build
        # kernels by now, and this one has time to spare (~15 s against the chain's ~24)
        _warm_parallel_queries(capped_tube()[0])
        seconds, n = time.perf_counter() - t0, _compiled_count()
    else:
        seconds, n = compile_kernels(progress=not args.quiet)
    if not args.quiet:
        from ..numba_cache import cache_root

        print(f"compiled or loaded {n} kernel specialisations in {seconds:.1f} s (cached for later runs in {cache_root()})")
    return 0


EXTRA_COMMANDS["compile"] = (add_arguments, run, HELP)
