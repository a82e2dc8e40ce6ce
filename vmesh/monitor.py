"""Wall time and peak memory of a block of work (per filter in a chain)."""

from __future__ import annotations

import os
import resource
import threading
import time

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Current resident set size of this process."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except OSError:  # not Linux: the peak is the best we have
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _high_water_mark() -> int | None:
    """The kernel's peak RSS of this process (``VmHWM``) in bytes, or None where not readable."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _reset_high_water_mark() -> bool:
    """Reset ``VmHWM`` to the current RSS (Linux >= 4.0: ``5`` into /proc/self/clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


#: Monitors open in this process, outermost first (a reset of the kernel's peak by an inner
#: one is first folded into the outer ones).
_OPEN: list = []


class ResourceMonitor:
    """Context manager measuring wall time, process CPU time and peak RSS.

    ``cpu_seconds`` is the process's CPU time (all threads, user + system) over the block: on
    a loaded machine it compares runs where the wall time does not.

    On Linux the peak is the kernel's own high-water mark (``VmHWM``), reset when the block
    starts: exact, with no cost while the block runs, and memory held by C extensions
    (pymeshlab, libigl, VTK) counts. Elsewhere a thread samples the RSS every ``interval``
    seconds (it wakes the interpreter, so it costs a little time under the GIL).
    """

    def __init__(self, interval: float = 0.005):
        self.interval = interval
        self.seconds = 0.0
        self.cpu_seconds = 0.0
        self.start_rss = 0
        self.peak_rss = 0
        self._stop = threading.Event()
        self._thread = None

    def _sample(self):
        while not self._stop.wait(self.interval):
            self.peak_rss = max(self.peak_rss, rss_bytes())

    def __enter__(self):
        self.start_rss = self.peak_rss = rss_bytes()
        hwm = _high_water_mark()
        if hwm is not None:
            for outer in _OPEN:  # the peak so far belongs to the blocks already open
                outer.peak_rss = max(outer.peak_rss, hwm)
        if hwm is None or not _reset_high_water_mark():
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()
        _OPEN.append(self)
        self._t0 = time.perf_counter()
        self._c0 = time.process_time()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self._t0
        self.cpu_seconds = time.process_time() - self._c0
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
        else:
            self.peak_rss = max(self.peak_rss, _high_water_mark() or 0)
        self.peak_rss = max(self.peak_rss, rss_bytes())
        if self in _OPEN:
            _OPEN.remove(self)
        for outer in _OPEN:
            outer.peak_rss = max(outer.peak_rss, self.peak_rss)
        return False

    @property
    def peak_mb(self) -> float:
        return self.peak_rss / 2**20

    @property
    def extra_mb(self) -> float:
        """Peak memory above what the process held when the block started."""
        return max(self.peak_rss - self.start_rss, 0) / 2**20
