"""Measuring coarse signed distances against the fine one: build time, query throughput
and projection error (``benchmarks/sdf_coarse_vs_fine.py``, the ``measure_sdf`` filter)."""

from __future__ import annotations

import numpy as np

from . import bvh as _bvh
from .sdf import SignedDistance, TwoStepSignedDistance, vessel_query_points


def projection_errors(fine: SignedDistance, result, fine_result) -> tuple[np.ndarray, np.ndarray]:
    """Errors of an approximate ``project`` result against the fine surface.

    Parameters
    ----------
    fine : SignedDistance of the fine surface
    result : (closest, distance, face) from the approximate (coarse or two-step) SDF
    fine_result : the same from ``fine.project`` at the same points

    Returns
    -------
    off_surface : (n,) distance of each projected point from the fine surface
        (the projection error; closest points themselves are not unique near the
        centreline, so their displacement is not a meaningful error)
    distance_error : (n,) absolute difference of the signed distances
    """
    off_surface = np.abs(fine.distance(result[0]))
    return off_surface, np.abs(result[1] - fine_result[1])


def compare_coarse_fine(fine_surface, coarse_surfaces, counts=(10_000, 100_000, 1_000_000), seed: int = 0, case: str = "", labels=None, octree: bool = True, repeat: int = 3) -> list[dict]:
    """Build time, query throughput and projection error of coarse SDFs against the fine one.

    For every number of points in ``counts`` and every coarse surface: project the same
    query points (:func:`vessel_query_points`, caps excluded when the fine surface has
    a ``cap_id`` face array) with the fine, the coarse and the two-step SDF. ``labels``
    name the coarse surfaces in the rows' ``coarse_level`` (default: their face counts).

    Returns
    -------
    list of dict rows with keys ``case, triangles_fine, triangles_coarse, points,
    build_s_fine, build_s_coarse, qps_fine, qps_coarse, speedup, err_max_rel,
    err_mean_rel`` (projection error relative to the local radius) plus
    ``err_max_abs, err_mean_abs, dist_err_max_rel, dist_err_mean_rel, cpu_qps_fine,
    cpu_qps_coarse`` (points per CPU-second, less sensitive to other load), ``qps_two_step,
    two_step_err_max_rel, two_step_dist_err_max_rel, two_step_dist_err_mean_rel,
    radius_median, coarse_level, coarse_index``.

    With ``octree`` every coarse surface, and the fine one, also gets an
    :class:`~vmesh.geometry.octree_sdf.OctreeSignedDistance` (its rows: ``coarse_index``
    ``"octree"``, ``coarse_level`` ending in ``", octree"``, ``build_s_coarse`` the BVH and
    the octree together). Times are the best of ``repeat`` runs (the first 10^6-point run
    of a kernel pays page faults and thread start-up that a mesher pays once).
    """
    import time

    t0 = time.perf_counter()
    fine = SignedDistance.from_surface(fine_surface)
    build_fine = time.perf_counter() - t0
    caps = fine_surface.face_data.get("cap_id")
    wall = None if caps is None or len(caps) != fine_surface.n_faces else np.asarray(caps) == 0
    labels = list(labels) if labels is not None else [f"{s.n_faces} faces" for s in coarse_surfaces]
    coarse, kinds = [], []
    for surface, label in zip(coarse_surfaces, labels):
        t0 = time.perf_counter()
        sdf = SignedDistance.from_surface(surface)
        coarse.append((sdf, time.perf_counter() - t0))
        kinds.append((label, "bvh"))
    if octree:
        from .octree_sdf import OctreeSignedDistance

        for (sdf, build_s), (label, _) in list(zip(coarse, kinds)) + [((fine, build_fine), ("fine surface", ""))]:
            t0 = time.perf_counter()
            tree = OctreeSignedDistance(sdf, wall_faces=wall if sdf is fine else None)
            coarse.append((tree, build_s + time.perf_counter() - t0))
            kinds.append((f"{label}, octree", "octree"))
    # warm-up (thread pool, page faults) of the serial and the parallel kernels, every surface
    warm = np.resize(fine.vertices, (_bvh.PARALLEL_MIN, 3))
    for sdf in [fine] + [c for c, _ in coarse]:
        sdf.project(warm[:16])
        sdf.project(warm)
    rows = []
    for n in counts:
        points, radius = vessel_query_points(fine, int(n), seed=seed, wall_faces=wall)
        ref, (wall_s, cpu_s) = _timed(fine.project, points, repeat=repeat)
        qps_fine, cpu_qps_fine = n / wall_s, n / cpu_s
        for (sdf, build_s), (label, kind) in zip(coarse, kinds):
            res, (wall_s, cpu_s) = _timed(sdf.project, points, repeat=repeat)
            qps_coarse, cpu_qps_coarse = n / wall_s, n / cpu_s
            two = TwoStepSignedDistance(sdf, fine)
            res2, (wall_s, _) = _timed(two.project, points, repeat=repeat)
            qps_two = n / wall_s
            off, derr = projection_errors(fine, res, ref)
            off2, derr2 = projection_errors(fine, res2, ref)
            rows.append(
                {
                    "case": case or fine_surface.name,
                    "triangles_fine": fine.n_faces,
                    "triangles_coarse": sdf.n_faces,
                    "coarse_level": label,
                    "coarse_index": kind,
                    "points": int(n),
                    "build_s_fine": round(build_fine, 4),
                    "build_s_coarse": round(build_s, 4),
                    "qps_fine": round(qps_fine),
                    "qps_coarse": round(qps_coarse),
                    "speedup": round(qps_coarse / qps_fine, 2),
                    "cpu_qps_fine": round(cpu_qps_fine),
                    "cpu_qps_coarse": round(cpu_qps_coarse),
                    "err_max_rel": float(np.max(off / radius)),
                    "err_mean_rel": float(np.mean(off / radius)),
                    "err_max_abs": float(off.max()),
                    "err_mean_abs": float(off.mean()),
                    "dist_err_max_rel": float(np.max(derr / radius)),
                    "dist_err_mean_rel": float(np.mean(derr / radius)),
                    "qps_two_step": round(qps_two),
                    "two_step_err_max_rel": float(np.max(off2 / radius)),
                    "two_step_dist_err_max_rel": float(np.max(derr2 / radius)),
                    "two_step_dist_err_mean_rel": float(np.mean(derr2 / radius)),
                    "radius_median": float(np.median(radius)),
                }
            )
    return rows


def _timed(function, *args, repeat: int = 1):
    """``(result, (wall seconds, CPU seconds of this process))``, the fastest of ``repeat`` runs."""
    import time

    best = (np.inf, np.inf)
    for _ in range(max(1, repeat)):
        w0, c0 = time.perf_counter(), time.process_time()
        out = function(*args)
        best = min(best, (max(time.perf_counter() - w0, 1e-9), max(time.process_time() - c0, 1e-9)))
    return out, best
