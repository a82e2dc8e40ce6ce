"""``mesh_transfinite.untangle_patience`` (opt-in, h26/slow): the local untangler's ring
patience reaches :func:`vmesh.geometry.optimize.optimise`, and its default leaves the growth
unbounded (the runs' meshes as before)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

import vmesh.filters.mesh_filters as mf
from vmesh.registry import get_filter


def _run_untangle(monkeypatch, **kw):
    """``mesh_filters._untangle`` on a stand-in mesh, with the local optimiser recording its
    keywords and keeping its result (minimum 1 > untangle_restart_below)."""
    seen = {}

    def optimise(points, cells, order, **args):
        seen.update(args)
        return np.array(points, float), {"after": {"min": 1.0}, "moved": 0, "untangled_nodes": 0, "smoothed_nodes": 0}

    import vmesh.geometry.optimize as opt

    monkeypatch.setattr(opt, "optimise", optimise)
    n = 8
    monkeypatch.setattr(mf, "_constraints", lambda sm: (np.zeros(n, bool), np.zeros((n, 3)), np.zeros(n, bool), np.zeros(n, bool)))
    kept = []
    monkeypatch.setattr(mf, "_keep_untangled", lambda ctx, sm, X, info, *a, **k: kept.append(X))
    sm = SimpleNamespace(order=1, points=np.zeros((n, 3)), cells=np.arange(8)[None, :])
    ctx = SimpleNamespace(tick=lambda *a, **k: None)
    mf._untangle(ctx, sm, None, SimpleNamespace(gradient=None), 0.3, 0.3, "local", **kw)
    assert len(kept) == 1  # the local result was kept: the global untangler did not run
    return seen


def test_patience_reaches_the_local_untangler(monkeypatch):
    assert _run_untangle(monkeypatch, patience=3)["untangle_patience"] == 3


def test_default_is_unbounded_growth(monkeypatch):
    params = {p.name: p for p in get_filter("mesh_transfinite").parameters}
    assert params["untangle_patience"].default == 0
    assert _run_untangle(monkeypatch)["untangle_patience"] is None


def test_patience_reaches_the_polish_climbs(monkeypatch):
    """With the global untangler's result, the climbs after it (``_polish``) get it too."""
    import vmesh.geometry.optimize as opt
    import vmesh.geometry.untangle as unt

    seen = {}
    n = 8
    monkeypatch.setattr(unt, "untangle", lambda points, cells, p, **k: (np.array(points, float), {"rounds": 1, "moved": 0}))

    def polish(X, cells, goals, **kw):
        seen.update(kw)
        return X, {"tries": []}

    monkeypatch.setattr(opt, "polish", polish)
    monkeypatch.setattr(mf, "_constraints", lambda sm: (np.zeros(n, bool), np.zeros((n, 3)), np.zeros(n, bool), np.zeros(n, bool)))
    monkeypatch.setattr(mf, "_keep_untangled", lambda *a, **k: None)
    sm = SimpleNamespace(order=1, points=np.zeros((n, 3)), cells=np.arange(8)[None, :])
    ctx = SimpleNamespace(tick=lambda *a, **k: None)
    mf._untangle(ctx, sm, None, SimpleNamespace(gradient=None), 0.3, 0.3, "lbfgs", patience=3)
    assert seen["untangle_patience"] == 3
