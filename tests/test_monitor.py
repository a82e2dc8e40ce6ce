"""ResourceMonitor: wall time and peak memory of a block, nested blocks, the sampling fallback."""

import numpy as np

from vmesh import monitor
from vmesh.monitor import ResourceMonitor


def _allocate(mb: int) -> float:
    a = np.ones(mb * 2**20 // 8)  # touched pages count in the RSS
    return float(a[-1])


def test_peak_counts_a_temporary_allocation():
    with ResourceMonitor() as m:
        _allocate(200)
    assert m.seconds > 0
    assert m.extra_mb > 150 and m.peak_mb >= m.extra_mb


def test_nested_blocks_keep_the_outer_peak():
    """An inner block resets the kernel's peak; the outer block still sees the inner peak and its own."""
    with ResourceMonitor() as outer:
        _allocate(200)
        with ResourceMonitor() as inner:
            _allocate(20)
        with ResourceMonitor() as inner2:
            _allocate(120)
    assert inner.extra_mb < 100 and inner2.extra_mb > 90
    assert outer.extra_mb > 150
    assert monitor._OPEN == []


def test_sampling_fallback(monkeypatch):
    """Without /proc's high-water mark, a sampling thread measures the peak."""
    monkeypatch.setattr(monitor, "_high_water_mark", lambda: None)
    with ResourceMonitor(interval=0.001) as m:
        a = np.ones(150 * 2**20 // 8)
        for _ in range(50):  # held long enough for the sampler to see it
            a += 1.0
        del a
    assert m.extra_mb > 100
