"""Whether a skeleton given to the skeleton filters fits the surface (other units, another
vessel, placeholder radii), and its pieces lying outside dropped: the checks
``estimate_radii`` and ``clean_skeleton`` share (docs/skeleton_fit.md)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..geometry.skeleton.defects import drop_outside_components


def _surface_bounds(ctx):
    if ctx.surface is not None:
        return ctx.surface.bounds
    if ctx.sdf is not None:
        return ctx.sdf.bounds
    return ctx.skeleton.points.min(axis=0), ctx.skeleton.points.max(axis=0)


def _drop_pieces_outside(ctx, skel, distance):
    """Remove the skeleton's pieces that lie mostly outside the surface (the centerlines of
    surface pieces repair_surface dropped), with a warning naming them."""
    skel, gone = drop_outside_components(skel, distance)
    if gone:
        where = "; ".join(f"{n} nodes about {np.round(c, 3).tolist()}" for n, c in gone)
        ctx.warn(f"removed {len(gone)} skeleton piece(s) lying outside the surface (of a surface piece not meshed?): {where}")
        ctx.count(pieces_outside=len(gone))
    return skel


def fit_to_surface(ctx, skel):
    """The one place where pieces outside the surface go (:func:`_drop_pieces_outside`)
    and the fit is judged (:func:`_check_fit`), in that order: a dropped piece must not
    count against the fit. ``estimate_radii`` calls it; ``clean_skeleton`` only when
    ``estimate_radii`` did not run (no ``skeleton_fit`` section), since nothing between
    them makes new pieces. Returns the skeleton and whether its radii are unknown."""
    skel = _drop_pieces_outside(ctx, skel, ctx.sdf.distance)
    return skel, _check_fit(ctx, skel)


#: Shares of a centerline's nodes farther outside the wall than their radius: above
#: FOREIGN_SHARE the run stops (most of it cannot be cleaned into place), above DOUBTFUL_SHARE
#: it warns (the given centerlines of the real and generated corpora reach 0.08 at most, at
#: ends running past open caps; another vessel's centerline 0.4 and more)
FOREIGN_SHARE = 0.5
DOUBTFUL_SHARE = 0.2


def _check_fit(ctx, skel) -> bool:
    """Fail when the skeleton does not fit the surface (other units, another vessel);
    returns whether its radii should be measured from the surface instead (all equal,
    or in other units than its coordinates)."""
    from ..geometry.skeleton_fit import centerline_fit

    fit = centerline_fit(skel, ctx.sdf.distance, _surface_bounds(ctx))
    ctx.report.sections["skeleton_fit"] = {
        "far_outside": round(fit.far_outside, 4),
        "inside": round(fit.inside, 4),
        "scale": fit.scale,
        "radius_ratio": None if fit.radius_ratio is None else round(fit.radius_ratio, 4),
    }
    sizes = f"(its extent {fit.extent:.4g}, the surface's {fit.surface_extent:.4g})"
    if fit.scale is not None:
        raise InputError(
            f"the centerline is in other units than the surface {sizes}: multiplied by {fit.scale:g} it spans "
            f"the surface with {100 * fit.details['inside_when_scaled'][fit.scale]:.0f} % of its nodes inside; "
            f"rerun with --set estimate_radii.scale={fit.scale:g}",
            ctx.inputs.get("skeleton"),  # the given centerline's file, named first
        )
    if fit.far_outside > FOREIGN_SHARE:
        raise InputError(
            f"{100 * fit.far_outside:.0f} % of centerline nodes lie outside the surface (farther than their radius "
            f"from the wall) {sizes}: is this the centerline of this vessel? Give its own centerline, or none to extract one",
            ctx.inputs.get("skeleton"),
        )
    if fit.far_outside > DOUBTFUL_SHARE:
        ctx.warn(
            f"{100 * fit.far_outside:.0f} % of centerline nodes lie outside the surface (farther than their radius "
            f"from the wall) {sizes}: is this the centerline of this vessel? Those nodes are dropped or pulled in; "
            "check the mesh's branches against the surface, or give none to extract one"
        )
    r = skel.radii[np.isfinite(skel.radii) & (skel.radii > 0)]
    depth = np.asarray(ctx.sdf.distance(skel.points), float)
    depth = depth[depth > 0]
    varies = len(depth) >= 3 and np.ptp(np.percentile(depth, [10, 90])) > 0.5 * np.median(depth)
    off = fit.radius_ratio is not None and not (0.8 <= fit.radius_ratio <= 1.25)
    if skel.n_nodes >= 3 and len(r) == skel.n_nodes and np.ptp(r) <= 1e-9 * r.max() and (varies or off):
        ctx.warn(f"all {skel.n_nodes} centerline radii are {r[0]:.4g}: taken as unknown and measured from the surface")
        return True
    if fit.radius_ratio is not None and not (1 / 3 <= fit.radius_ratio <= 3):
        ctx.warn(
            f"the centerline's radii are {fit.radius_ratio:.3g} times the surface's inscribed radii (other units?): "
            "measured from the surface instead"
        )
        return True
    return False
