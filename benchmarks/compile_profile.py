"""Where a cold first run's compile time goes: CPU seconds per numba dispatcher.

Runs ``vmesh`` in this process with numba's ``numba:compile`` events recorded and prints the
CPU seconds and number of compiles per dispatcher (inclusive: a kernel's time contains the
callees compiled while typing it), then the run's total CPU and wall seconds. Point
``NUMBA_CACHE_DIR`` at an empty folder for a cold run (the cache beside the sources is then
left alone)::

    NUMBA_CACHE_DIR=$(mktemp -d) python benchmarks/compile_profile.py run default -q \\
        -i data_synthetic/y_bifurcation/surface.ply -o /tmp/out
"""

from __future__ import annotations

import collections
import sys
import time

from numba.core import event


class _Recorder(event.Listener):
    """CPU seconds and count of compiles per dispatcher."""

    def __init__(self):
        self.start, self.seconds, self.count = {}, collections.Counter(), collections.Counter()

    def on_start(self, ev):
        self.start[id(ev.data["dispatcher"]), str(ev.data["args"])] = time.process_time()

    def on_end(self, ev):
        d = ev.data["dispatcher"]
        t0 = self.start.pop((id(d), str(ev.data["args"])), time.process_time())
        name = f"{d.py_func.__module__.rsplit('.', 1)[-1]}.{d.py_func.__name__}"
        self.seconds[name] += time.process_time() - t0
        self.count[name] += 1


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):  # its own usage, not vmesh's
        print(__doc__)
        return 0
    rec = _Recorder()
    event.register("numba:compile", rec)
    c, t = time.process_time(), time.perf_counter()
    from vmesh.cli import main as vmesh_main

    try:
        vmesh_main(argv)
    except SystemExit:
        pass
    print(f"total {time.process_time() - c:.1f} s CPU, {time.perf_counter() - t:.1f} s wall")
    print("| CPU s | compiles | dispatcher |\n|---|---|---|")
    for name, s in rec.seconds.most_common(25):
        print(f"| {s:.2f} | {rec.count[name]} | {name} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
