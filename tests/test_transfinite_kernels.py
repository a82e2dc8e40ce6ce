"""The compiled transfinite kernels against the vectorised numpy implementations they
replaced (kept here as references), on random graded lattices of order 1, 2 and 3."""

import numpy as np
import pytest

from vmesh.geometry.transfinite import (
    _interp_rows,
    coons_patch,
    element_boundaries,
    geometric_ratio,
    reference_points,
    regrade_lines,
    transfinite_volume,
    with_order,
)


# ---------------------------------------------------------------------------
# numpy references (the former implementations)
# ---------------------------------------------------------------------------
def geometric_ratio_ref(first, length, n):
    first = np.asarray(first, float)
    length = np.asarray(length, float)
    target = length / np.maximum(first, 1e-300)
    lo = np.ones_like(target)
    hi = np.full_like(target, 2.0)
    for _ in range(60):
        s = (hi**n - 1) / (hi - 1)
        grow = s < target
        if not grow.any():
            break
        hi = np.where(grow, hi * 2, hi)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        s = np.where(np.abs(mid - 1) < 1e-12, n, (mid**n - 1) / np.maximum(mid - 1, 1e-300))
        too_big = s > target
        hi = np.where(too_big, mid, hi)
        lo = np.where(too_big, lo, mid)
    q = 0.5 * (lo + hi)
    return np.where(target <= n, 1.0, q)


def interp_rows_ref(x, xp, fp):
    m, k = xp.shape
    lo = xp[:, :1]
    span = np.maximum(xp[:, -1:] - lo, 1e-300)
    offset = 3.0 * np.arange(m)[:, None]
    flat_xp = ((xp - lo) / span + offset).ravel()
    flat_x = (np.clip((x - lo) / span, 0.0, 1.0) + offset).ravel()
    idx = np.searchsorted(flat_xp, flat_x, side="right") - 1
    row_start = (np.arange(m) * k)[:, None]
    idx = np.clip(idx.reshape(x.shape) - row_start, 0, k - 2)
    x0 = np.take_along_axis(xp, idx, 1)
    x1 = np.take_along_axis(xp, idx + 1, 1)
    w = np.clip(np.where(x1 > x0, (x - x0) / np.maximum(x1 - x0, 1e-300), 0.0), 0.0, 1.0)
    if fp.ndim == 3:
        idx, w = idx[..., None], w[..., None]
    f0 = np.take_along_axis(fp, idx, 1)
    f1 = np.take_along_axis(fp, idx + 1, 1)
    return f0 + w * (f1 - f0)


def edge_params_ref(curve):
    seg = np.linalg.norm(np.diff(curve, axis=-2), axis=-1)
    s = np.concatenate([np.zeros(seg.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)
    return s / np.maximum(s[..., -1:], 1e-300)


def coons_patch_ref(P):
    P = P.copy()
    B, T = P[:, :, 0], P[:, :, -1]
    Lf, R = P[:, 0, :], P[:, -1, :]
    sb, st = edge_params_ref(B), edge_params_ref(T)
    vl, vr = edge_params_ref(Lf), edge_params_ref(R)
    t_mean = 0.5 * (vl + vr)[:, None, :]
    s_mean = 0.5 * (sb + st)[:, :, None]
    u = ((1 - t_mean) * sb[:, :, None] + t_mean * st[:, :, None])[..., None]
    v = ((1 - s_mean) * vl[:, None, :] + s_mean * vr[:, None, :])[..., None]
    c00, c10, c01, c11 = P[:, :1, :1], P[:, -1:, :1], P[:, :1, -1:], P[:, -1:, -1:]
    inner = (
        (1 - v) * B[:, :, None] + v * T[:, :, None] + (1 - u) * Lf[:, None, :] + u * R[:, None, :]
        - ((1 - u) * (1 - v) * c00 + u * (1 - v) * c10 + (1 - u) * v * c01 + u * v * c11)
    )
    P[:, 1:-1, 1:-1] = inner[:, 1:-1, 1:-1]
    return P


def transfinite_volume_ref(P):
    P = P.copy()
    ui = edge_params_ref(P[:, :, [0, 0, -1, -1], [0, -1, 0, -1]].transpose(0, 2, 1, 3)).mean(axis=1)
    vj = edge_params_ref(P[:, [0, 0, -1, -1], :, [0, -1, 0, -1]].transpose(1, 0, 2, 3)).mean(axis=1)
    wk = edge_params_ref(P[:, [0, 0, -1, -1], [0, -1, 0, -1], :]).mean(axis=1)
    u = ui[:, :, None, None, None]
    v = vj[:, None, :, None, None]
    w = wk[:, None, None, :, None]
    W = (1 - u) * P[:, :1] + u * P[:, -1:]
    W += (1 - v) * (P[:, :, :1] - W[:, :, :1]) + v * (P[:, :, -1:] - W[:, :, -1:])
    W += (1 - w) * (P[:, :, :, :1] - W[:, :, :, :1]) + w * (P[:, :, :, -1:] - W[:, :, :, -1:])
    P[:, 1:-1, 1:-1, 1:-1] = W[:, 1:-1, 1:-1, 1:-1]
    return P


def regrade_lines_ref(P, axis, wall_first, h1, n, p, kind):
    if n < 2:
        return P
    Q = np.moveaxis(P, axis, -2)
    shape = Q.shape
    m, k = shape[0], shape[-2]
    lines = Q.reshape(m, -1, k, 3)
    flip = ~np.asarray(wall_first, bool)
    lines = np.where(flip[:, None, None, None], lines[:, :, ::-1], lines)
    seg = np.linalg.norm(np.diff(lines, axis=2), axis=3)
    s = np.concatenate([np.zeros(seg.shape[:2] + (1,)), np.cumsum(seg, axis=2)], axis=2)
    length = s[..., -1]
    ratio = geometric_ratio_ref(np.repeat(h1[:, None], lines.shape[1], 1).ravel(), length.ravel(), n)
    target = with_order(element_boundaries(n, ratio), p, kind).reshape(s.shape) * length[..., None]
    flat = lines.reshape(-1, k, 3)
    new = interp_rows_ref(target.reshape(-1, k), s.reshape(-1, k), flat)
    new = new.reshape(lines.shape)
    new = np.where(flip[:, None, None, None], new[:, :, ::-1], new)
    out = np.moveaxis(new.reshape(shape), -2, axis)
    res = P.copy()
    inner = tuple([slice(None)] + [slice(None) if d == axis else slice(1, -1) for d in range(1, P.ndim - 1)])
    res[inner] = out[inner]
    return res


# ---------------------------------------------------------------------------
# random graded lattices
# ---------------------------------------------------------------------------
def graded_params(rng, n, p, kind="gauss_lobatto"):
    """Lattice parameters (n p + 1,) of n elements with a random geometric grading."""
    q = rng.uniform(0.6, 1.6)
    return with_order(element_boundaries(n, q), p, kind)[0]


def random_lattices(rng, m, counts, p, noise=0.03):
    """(m, N1+1, ..., 3) lattices: a random smooth map of graded parameter grids plus noise."""
    out = []
    for _ in range(m):
        axes = [graded_params(rng, n, p) for n in counts]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        if len(counts) == 2:
            grid = np.concatenate([grid, np.zeros(grid.shape[:-1] + (1,))], axis=-1)
        A = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
        x = grid @ A.T + 0.2 * np.sin(3 * grid[..., [1, 2, 0]] + rng.normal(size=3)) + rng.normal(size=3)
        out.append(x + noise * rng.normal(size=x.shape))
    return np.stack(out)


@pytest.mark.parametrize("n", [2, 3, 5, 12])
def test_geometric_ratio_matches_bisection(n):
    rng = np.random.default_rng(n)
    first = rng.uniform(1e-4, 0.5, 500)
    length = rng.uniform(0.1, 2.0, 500)
    q = geometric_ratio(first, length, n)
    assert np.allclose(q, geometric_ratio_ref(first, length, n), rtol=1e-12, atol=0)
    # near-uniform edges (target just above n; the bisection's (q**n - 1) / (q - 1) cancels
    # there, the compiled sum form does not) and uniform ones (ratio 1)
    first = np.full(5, 0.1)
    length = 0.1 * n * np.array([0.5, 1 + 1e-6, 1 + 1e-3, 1.1, 3.0])
    assert np.allclose(geometric_ratio(first, length, n), geometric_ratio_ref(first, length, n), rtol=1e-9, atol=0)
    assert abs(geometric_ratio(0.1, 0.1 * n, n) - 1) < 1e-12
    assert geometric_ratio(0.1, 1.0, n).shape == ()


@pytest.mark.parametrize("d", [0, 3])
def test_interp_rows_matches_reference(d):
    rng = np.random.default_rng(d)
    xp = np.cumsum(rng.uniform(0, 1, (40, 9)), axis=1)
    xp[3, 4] = xp[3, 3]  # a repeated node
    x = np.sort(rng.uniform(-1, 10, (40, 13)), axis=1)
    x[5] = x[5, ::-1]  # not ascending
    x[:, 0] = xp[:, 2]  # exactly on a node
    fp = rng.normal(size=(40, 9, d) if d else (40, 9))
    got = _interp_rows(x, xp, fp)
    assert got.shape == fp.shape[:1] + x.shape[1:] + fp.shape[2:]
    assert np.allclose(got, interp_rows_ref(x, xp, fp), rtol=0, atol=1e-12)


@pytest.mark.parametrize("p", [1, 2, 3])
def test_coons_patch_matches_reference(p):
    rng = np.random.default_rng(p)
    P = random_lattices(rng, 20, (3, 4), p)
    P[:, 1:-1, 1:-1] = np.nan  # the interior is not read
    ref = coons_patch_ref(np.nan_to_num(P))
    got = coons_patch(P)
    assert np.abs(got - ref).max() < 1e-12


@pytest.mark.parametrize("p", [1, 2, 3])
def test_transfinite_volume_matches_reference(p):
    rng = np.random.default_rng(10 + p)
    P = random_lattices(rng, 12, (2, 3, 4), p)
    P[:, 1:-1, 1:-1, 1:-1] = np.nan
    ref = transfinite_volume_ref(np.nan_to_num(P))
    got = transfinite_volume(P)
    assert np.abs(got - ref).max() < 1e-12


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("kind", ["gauss_lobatto", "equispaced"])
def test_regrade_lines_matches_reference(p, kind):
    rng = np.random.default_rng(20 + p)
    counts = (3, 4, 2)
    P = random_lattices(rng, 10, counts, p, noise=0.005)
    for axis in (1, 2, 3):
        n = counts[axis - 1]
        wall_first = rng.random(10) < 0.5
        h1 = rng.uniform(0.002, 0.05, 10)
        got = regrade_lines(P, axis, wall_first, h1, n, p, kind)
        ref = regrade_lines_ref(P, axis, wall_first, h1, n, p, kind)
        assert np.abs(got - ref).max() < 1e-12
    F = P[:, :, :, 0]  # faces
    for axis in (1, 2):
        n = counts[axis - 1]
        wall_first = rng.random(10) < 0.5
        h1 = rng.uniform(0.002, 0.05, 10)
        assert np.abs(regrade_lines(F, axis, wall_first, h1, n, p, kind) - regrade_lines_ref(F, axis, wall_first, h1, n, p, kind)).max() < 1e-12
