"""Variation filters for parameter studies (thin wrappers of :mod:`vmesh.geometry.variation`).

They change the input geometry, so they belong at the start of a chain, before the
signed distance is built (``filters/batch_sweep.toml``).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..registry import Parameter, register_filter


@register_filter(
    description="Scale the vessel radii about the centerline: each surface vertex moves along its offset from the skeleton by the factor; skeleton radii are scaled too.",
    parameters=[
        Parameter("scale", "float", 1.0, "Radius factor (1: unchanged).", min=0.05, max=20.0),
        Parameter("blend", "float", 0.2, "Width of the blend between neighbouring segments (junctions, inner side of bends), relative to the distance from the centerline.", min=1e-3, max=2.0),
        Parameter("end_extension", "float", 2.0, "Terminal segments extend this far past their free end, so flat end caps stay in their planes.", unit="× radius", min=0.0, max=20.0),
    ],
    reads=("surface",),
    optional_reads=("skeleton",),
    writes=("surface", "skeleton"),
    updates=("skeleton",),
    category="input",
)
def scale_radius(ctx, scale, blend, end_extension):
    """Move every vertex ``v`` to ``c + scale · (v - c)``, ``c`` its (blended) closest
    point on the skeleton, so the centerline stays and only the radii change.

    Run it before ``build_sdf``: the signed distance, caps and block structure must
    see the scaled surface. With ``scale = 1`` it changes nothing and needs no skeleton.
    """
    if scale == 1.0:
        ctx.count(scale=1.0, moved_vertices=0)
        return
    skel = ctx.skeleton
    if skel is None:
        raise InputError("scale_radius needs a skeleton (give one with --skeleton / the manifest's skeleton column)")
    if skel.n_edges == 0:
        raise InputError("scale_radius needs a skeleton with at least one segment", skel.name or None)
    from ..geometry.variation import scale_radii

    s = ctx.surface
    vertices, info = scale_radii(s.vertices, skel.points, skel.radii, skel.edges, scale, blend=blend, end_extension=end_extension)
    ctx.surface = s.copy(vertices=vertices)
    ctx.skeleton = skel.copy(radii=skel.radii * scale)
    ctx.report.sections["scale_radius"] = {"scale": scale, "max_offset": info["max_offset"], "blended_vertices": info["blended"]}
    ctx.count(scale=scale, moved_vertices=int(np.count_nonzero(np.any(vertices != s.vertices, axis=1))), blended=info["blended"])
