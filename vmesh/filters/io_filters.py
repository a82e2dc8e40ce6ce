"""Input/output filters: surface diagnostics, transforms and writing layers to files."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..registry import Parameter, register_filter


@register_filter(
    description="Check the input surface: triangles, open boundary loops, non-manifold edges, orientation, bounding box.",
    parameters=[
        Parameter("require_closed", "bool", False, "Fail when the surface has open boundary loops (not capped yet)."),
        Parameter("require_manifold", "bool", False, "Fail when some edge is shared by more than two faces."),
    ],
    reads=("surface",),
    category="input",
)
def surface_info(ctx, require_closed, require_manifold):
    """Diagnose the surface and record the result in the report's ``surface`` section."""
    info = ctx.surface.info()
    ctx.report.sections.setdefault("surface", {}).update(info.as_dict())  # keeps what repair_surface recorded
    ctx.count(triangles=info.n_triangles, open_loops=info.n_boundary_loops, nonmanifold_edges=info.n_nonmanifold_edges)
    name = ctx.surface.name or "surface"
    if require_closed and not info.closed:
        raise InputError(f"surface has {info.n_boundary_loops} open boundary loops (add cap_open_ends)", name)
    if require_manifold and not info.manifold:
        raise InputError(f"surface has {info.n_nonmanifold_edges} non-manifold edges (add repair_surface)", name)
    if not info.consistently_oriented:
        ctx.warn("faces are not consistently oriented (repair_surface fixes this)")


@register_filter(
    description="Scale and translate the surface (and skeleton), e.g. to convert metres to millimetres.",
    parameters=[
        Parameter("scale", "float", 1.0, "Multiply every coordinate by this factor.", min=1e-12),
        Parameter("translate", "float_list", [0.0, 0.0, 0.0], "Then add this vector.", unit="mm"),
    ],
    reads=("surface",),
    optional_reads=("skeleton",),
    writes=("surface", "skeleton"),
    updates=("skeleton",),
    category="input",
)
def transform_surface(ctx, scale, translate):
    if len(translate) != 3:
        raise InputError("translate needs three numbers")
    t = np.asarray(translate, float)
    ctx.surface = ctx.surface.copy(vertices=ctx.surface.vertices * scale + t)
    if ctx.skeleton is not None:
        ctx.skeleton = ctx.skeleton.copy(points=ctx.skeleton.points * scale + t, radii=ctx.skeleton.radii * scale)


@register_filter(
    description="Write a surface layer (input or coarse) to a file in the output folder.",
    parameters=[
        Parameter("layer", "str", "surface", "Which surface to write.", choices=("surface", "coarse_surface")),
        Parameter("filename", "str", "surface.ply", "File name in the output folder; the extension picks the format (ply, stl, obj, vtp, vtk, off)."),
    ],
    optional_reads=("surface", "coarse_surface"),
    category="export",
)
def write_surface_layer(ctx, layer, filename):
    from ..io.surface import write_surface

    surface = getattr(ctx, layer)
    if surface is None:
        raise InputError(f"there is no {layer} layer to write")
    path = ctx.output_file(filename)
    if path is None:
        return
    write_surface(path, surface)


@register_filter(
    description="Write the skeleton to a file in the output folder (json, swc, vtp, ply).",
    parameters=[Parameter("filename", "str", "skeleton.json", "File name in the output folder; the extension picks the format.")],
    reads=("skeleton",),
    category="export",
)
def write_skeleton_layer(ctx, filename):
    from ..io.skeleton import write_skeleton

    path = ctx.output_file(filename)
    if path is None:
        return
    write_skeleton(path, ctx.skeleton)
