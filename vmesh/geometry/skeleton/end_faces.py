"""Flat end faces: their normals and the last full cross-section behind them.

A clipped vessel end is a rough, possibly tilted face with a rounded rim; the
skeleton must end on the axis a little behind it, where a cross-section meets only
the side wall (its boundary-layer blocks fold on the face otherwise).
"""

from __future__ import annotations

import numpy as np

from .probe import SdfFunction, center_in_cross_sections, distance_to_wall, plane_basis, sdf_gradient


def flat_end_sections(
    sdf: SdfFunction,
    faces: np.ndarray,
    normals: np.ndarray,
    tangents: np.ndarray,
    radii: np.ndarray,
    setbacks=(0.25, 0.5, 0.75, 1.0),
    rays: int = 16,
    max_wall_angle: float = 30.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The last full cross-section behind each flat end face.

    A cross-section on a clipped end face itself runs along the face's bumps and its
    rounded rim, not along the vessel wall: its rays are short on one side, and the
    boundary-layer blocks projected onto the wall there fold. Candidates are set back
    from the face centre along the inward face normal by ``setbacks`` x the radius,
    centred in the plane orthogonal to the axis; the first one whose ``rays`` in-plane
    rays all meet the wall where it is within ``max_wall_angle`` of parallel to the axis
    (the side wall, not the face or its rim) is kept; where none is, the one with the
    most such rays (the nearest of those).

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    faces, normals : (n, 3)
        Centres of the end faces and their outward unit normals.
    tangents : (n, 3)
        Unit vessel axes at the ends (outward).
    radii : (n,)
        Vessel radii near the ends.
    setbacks : sequence of float
        Candidate distances behind the face, in radii, nearest first.
    rays : int
        Rays per candidate section.
    max_wall_angle : float
        Largest angle (degrees) between the axis and the wall the rays meet.

    Returns
    -------
    centres : (n, 3)
        The chosen section centres.
    section : (n,)
        Their section radii (mean half-chord, see :func:`center_in_cross_sections`).
    setback : (n,)
        The chosen setbacks, in radii.
    """
    faces = np.asarray(faces, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    radii = np.asarray(radii, float).reshape(-1)
    n, s = len(faces), np.asarray(setbacks, float)
    m = len(s)
    # candidates (n, m) flattened end by end
    probes = faces[:, None, :] - (radii[:, None] * s[None, :])[..., None] * normals[:, None, :]
    r = np.repeat(radii, m)
    t = np.repeat(np.asarray(tangents, float).reshape(-1, 3), m, axis=0)
    centres, section = center_in_cross_sections(sdf, probes.reshape(-1, 3), t, r)
    e1, e2 = plane_basis(t)
    ang = 2 * np.pi * np.arange(rays) / rays
    dirs = (np.cos(ang)[None, :, None] * e1[:, None, :] + np.sin(ang)[None, :, None] * e2[:, None, :]).reshape(-1, 3)
    origins = np.repeat(centres, rays, axis=0)
    hit = distance_to_wall(sdf, origins, dirs, np.repeat(2.5 * r, rays), samples=20)
    found = np.isfinite(hit) & (hit > 0)
    back = np.repeat(0.05 * r, rays)  # the wall normal just inside the hit
    g = sdf_gradient(sdf, origins + (np.where(found, hit, 0.0) - back)[:, None] * dirs, back)
    along = np.abs(np.einsum("ij,ij->i", g, np.repeat(t, rays, axis=0)))
    side = (found & (along < np.sin(np.radians(max_wall_angle)))).reshape(n, m, rays).sum(axis=2)
    side = np.where(np.isfinite(section).reshape(n, m), side, -1)
    pick = np.argmax(side == side.max(axis=1, keepdims=True), axis=1)
    rows = np.arange(n)
    return centres.reshape(n, m, 3)[rows, pick], section.reshape(n, m)[rows, pick], s[pick]



def end_face_normals(sdf: SdfFunction, centres: np.ndarray, tangents: np.ndarray, radii: np.ndarray, reach: np.ndarray, rings: int = 2, per_ring: int = 8) -> np.ndarray:
    """Outward normals of the end faces ahead of points on the vessel axis.

    From a disc of points around each centre (up to half a radius from the axis, half a
    radius behind it) rays are cast along the axis; a least-squares plane through the
    wall points they meet gives the normal, pointing along ``tangents``. Where fewer
    than five rays meet the wall the SDF gradient at the axis' wall point is used.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    centres, tangents : (n, 3)
        Points on the vessel axis near its end and the unit axis directions (outward).
    radii : (n,)
        Vessel radii.
    reach : (n,)
        How far ahead the rays look for the wall.
    rings, per_ring : int
        Rings of the disc of ray origins and rays per ring (plus one on the axis).

    Returns
    -------
    (n, 3) unit normals.
    """
    c = np.asarray(centres, float).reshape(-1, 3)
    t = np.asarray(tangents, float).reshape(-1, 3)
    r = np.asarray(radii, float).reshape(-1)
    n = len(c)
    e1, e2 = plane_basis(t)
    ang = 2 * np.pi * np.arange(per_ring) / per_ring
    frac = np.r_[0.0, np.repeat(np.arange(1, rings + 1) / rings * 0.5, per_ring)]  # × radius off the axis
    cos = np.r_[0.0, np.tile(np.cos(ang), rings)]
    sin = np.r_[0.0, np.tile(np.sin(ang), rings)]
    k = len(frac)
    offset = (frac * cos)[None, :, None] * e1[:, None, :] + (frac * sin)[None, :, None] * e2[:, None, :]
    origins = c[:, None, :] + r[:, None, None] * (offset - 0.5 * t[:, None, :])
    dirs = np.repeat(t[:, None, :], k, axis=1)
    hit = distance_to_wall(sdf, origins.reshape(-1, 3), dirs.reshape(-1, 3), np.repeat(np.asarray(reach, float) + 0.5 * r, k), samples=24).reshape(n, k)
    good = np.isfinite(hit) & (hit > 0)
    points = origins + np.where(good, hit, 0.0)[..., None] * dirs
    # fallback: the gradient where the axis meets the wall
    axis_hit = np.where(good[:, 0], hit[:, 0], 0.5 * r)
    normal = -sdf_gradient(sdf, origins[:, 0] + (axis_hit - 0.1 * r)[:, None] * t, 0.05 * r)
    w = good.astype(float)
    count = w.sum(axis=1)
    mean = (points * w[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    rel = (points - mean[:, None, :]) * w[..., None]
    cov = np.einsum("nki,nkj->nij", rel, rel)
    fit = np.linalg.eigh(cov)[1][:, :, 0]  # smallest principal axis
    fit *= np.where(np.einsum("ij,ij->i", fit, t) < 0, -1.0, 1.0)[:, None]
    return np.where((count >= 5)[:, None], fit, normal)

