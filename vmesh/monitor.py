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


class ResourceMonitor:
    """Context manager measuring wall time and peak RSS.

    A sampling thread reads the RSS every ``interval`` seconds, so memory held by
    C extensions (pymeshlab, libigl, VTK) is counted, not just Python objects.
    """

    def __init__(self, interval: float = 0.005):
        self.interval = interval
        self.seconds = 0.0
        self.start_rss = 0
        self.peak_rss = 0
        self._stop = threading.Event()

    def _sample(self):
        while not self._stop.wait(self.interval):
            self.peak_rss = max(self.peak_rss, rss_bytes())

    def __enter__(self):
        self.start_rss = self.peak_rss = rss_bytes()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self._t0
        self._stop.set()
        self._thread.join()
        self.peak_rss = max(self.peak_rss, rss_bytes())
        return False

    @property
    def peak_mb(self) -> float:
        return self.peak_rss / 2**20

    @property
    def extra_mb(self) -> float:
        """Peak memory above what the process held when the block started."""
        return max(self.peak_rss - self.start_rss, 0) / 2**20
