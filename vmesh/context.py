"""The run context: one object holding a run's named layers and its report."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np


@dataclass
class StepReport:
    """What one filter did: time, memory, counts and warnings."""

    filter: str
    params: dict
    seconds: float = 0.0
    #: process CPU time (all threads) of the step
    cpu_seconds: float = 0.0
    peak_memory_mb: float = 0.0
    extra_memory_mb: float = 0.0
    counts: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    #: restored from a :class:`~vmesh.cache.PrefixCache` instead of run
    cached: bool = False


@dataclass
class Report:
    """A run's report: per-filter steps plus result sections (quality, distances...)."""

    steps: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    sections: dict = field(default_factory=dict)
    total_s: float = 0.0

    @property
    def timings(self) -> dict:
        """Seconds per filter; a filter run twice is listed as ``name``, ``name#2``."""
        out: dict = {}
        for s in self.steps:
            key, k = s.filter, 2
            while key in out:
                key, k = f"{s.filter}#{k}", k + 1
            out[key] = round(s.seconds, 6)
        return out

    def to_dict(self) -> dict:
        d = {
            "counts": _plain(self.counts),
            "timings": self.timings,
            "total_s": round(self.total_s, 6),
            "warnings": list(self.warnings),
        }
        d.update(_plain(self.sections))
        d["steps"] = [
            {
                "filter": s.filter,
                "seconds": round(s.seconds, 6),
                "cpu_seconds": round(s.cpu_seconds, 6),
                "peak_memory_mb": round(s.peak_memory_mb, 1),
                "extra_memory_mb": round(s.extra_memory_mb, 1),
                "counts": _plain(s.counts),
                "warnings": list(s.warnings),
                **({"cached": True} if s.cached else {}),
            }
            for s in self.steps
        ]
        return d

    def summary_table(self) -> str:
        """Per-filter table printed at the end of a command-line run."""
        rows = [("filter", "seconds", "peak MB", "+MB", "results")]
        for s in self.steps:
            counts = ("(cached) " if s.cached else "") + ", ".join(f"{k}={_fmt(v)}" for k, v in s.counts.items())
            rows.append((s.filter, f"{s.seconds:.3f}", f"{s.peak_memory_mb:.0f}", f"{s.extra_memory_mb:.0f}", counts))
        rows.append(("total", f"{self.total_s:.3f}", "", "", ""))
        w = [max(len(r[i]) for r in rows) for i in range(4)]
        lines = []
        for i, r in enumerate(rows):
            lines.append(f"{r[0]:<{w[0]}}  {r[1]:>{w[1]}}  {r[2]:>{w[2]}}  {r[3]:>{w[3]}}  {r[4]}".rstrip())
            if i == 0 or i == len(rows) - 2:
                lines.append("-" * min(100, sum(w) + 6 + max(len(r[4]) for r in rows)))
        return "\n".join(lines)


def _fmt(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _plain(obj, other=None):
    """Convert numpy scalars/arrays inside nested dicts to JSON-friendly values; paths
    become strings, any other value goes through ``other`` (kept as it is by default;
    ``str`` makes the result JSON-safe, as the pymeshlab filter needs for its results)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v, other) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, other) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if other is None or isinstance(obj, (int, float, str, bool)) or obj is None:
        return obj
    return other(obj)


@dataclass
class Context:
    """Everything one run of a filter chain reads and writes.

    Layers (``None`` until a filter or the caller provides them):

    surface
        The input (*fine*) :class:`~vmesh.surface.SurfaceMesh`, after preprocessing.
    coarse_surface
        A decimated copy used for a fast signed distance.
    caps
        List of :class:`~vmesh.preprocess.Cap` (named open ends: inlets/outlets).
    sdf
        A :class:`~vmesh.geometry.sdf.SignedDistance` (negative outside the vessel).
    skeleton
        The centerline graph, :class:`~vmesh.skeleton.Skeleton`.
    blocks
        The :class:`~vmesh.blocks.BlockStructure`.
    mesh
        The hexahedral mesh.
    quality
        Per-element quality arrays and summaries.
    """

    surface: Any = None
    coarse_surface: Any = None
    caps: Any = None
    sdf: Any = None
    skeleton: Any = None
    blocks: Any = None
    mesh: Any = None
    quality: Any = None
    report: Report = field(default_factory=Report)
    #: folder where output files are staged during a run (moved to ``out_dir`` at the end)
    stage_dir: Path | None = None
    out_dir: Path | None = None
    inputs: dict = field(default_factory=dict)
    progress: Callable | None = None
    #: a :class:`~vmesh.cache.PrefixCache`: steps up to the signed distance are reused from it
    cache: Any = None
    _step: StepReport | None = None

    def has(self, layer: str) -> bool:
        return getattr(self, layer) is not None

    def __repr__(self) -> str:
        """The layers present, each by its own short repr (caps and quality by their counts)."""
        parts = []
        for layer in ("surface", "coarse_surface", "caps", "sdf", "skeleton", "blocks", "mesh", "quality"):
            value = getattr(self, layer)
            if value is None:
                continue
            if layer == "caps":
                value = f"[{len(value)} caps]"
            elif layer == "quality":
                value = {k: value.get("summary", {}).get(k) for k in ("min", "mean", "n_invalid")}
            parts.append(f"{layer}={value!r}" if not isinstance(value, str) else f"{layer}={value}")
        parts.append(f"out_dir={None if self.out_dir is None else str(self.out_dir)!r}")
        return f"Context({', '.join(parts)})"

    def output_path(self, name: str) -> Path | None:
        """Where a filter should write output file ``name``; ``None`` when the run has no output folder."""
        if self.stage_dir is None:
            return None
        path = Path(self.stage_dir) / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def output_file(self, name: str) -> Path | None:
        """:meth:`output_path`, or ``None`` with the warning "no output folder: NAME not
        written" when the run has no output folder: the start of every file writer."""
        path = self.output_path(name)
        if path is None:
            self.warn(f"no output folder: {name} not written")
        return path

    def count(self, **counts) -> None:
        """Record result counts of the current filter (shown in the summary table)."""
        target = self._step.counts if self._step is not None else self.report.counts
        target.update(counts)

    def warn(self, message: str) -> None:
        """Record a warning (kept in the report and printed by the command line)."""
        where = self._step.filter if self._step is not None else "vmesh"
        text = f"{where}: {message}"
        self.report.warnings.append(text)
        if self._step is not None:
            self._step.warnings.append(message)
        if self.progress is not None:
            print(f"  warning: {message}", file=sys.stderr)

    def tick(self, fraction: float, message: str = "") -> None:
        """Report progress of long work inside a filter (0..1)."""
        if self.progress is not None:
            self.progress(fraction, message)
