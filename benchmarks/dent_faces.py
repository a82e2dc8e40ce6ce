"""What the wall does under the boundary-layer blocks the builder flags ("may fold when their
faces are projected onto the wall", ``blocks.info["wall_fold_blocks"]``).

For every wall face (i/j sides) of a flagged block, sampled on the builder's 5 x 5 grid
(:func:`vmesh.geometry.blocks.checks.projected_wall_quality`): the projected quality, the
layer's thickness there (the mean of the face's four radial block edges), how far the chord
between the wall corners runs outside the vessel (least signed distance of the wall grid,
negative outside), how much room the layer's inner face keeps (least signed distance of the
opposite face's grid), where the projected wall lands along the layer (``(projected -
inner) . (wall - inner) / |wall - inner|^2``, least over the grid: 1 on the wall grid, 0 on the
inner face, negative beyond it), along which block axis the chord dips deepest (along the
skeleton: between two cross-sections; around: between two rays of one section), and how many
of its grid points have their closest point on the closed surface (caps included) on a cap
triangle, although the wall projector (caps excluded) sends them to the wall. The domain
and projector are the mesher's (contact cuts included).

    PYTHONPATH=$PWD python3 benchmarks/dent_faces.py SURFACE [--skeleton FILE] --prefix /tmp/x.pkl [--json OUT]

The prefix pickle is :mod:`fold_stages`' (the chain through ``build_block_structure``).
docs/optimiser.md, "Dents under the flagged boundary-layer blocks" (h16/dents).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fold_stages import prefix_arguments, prefix_context  # noqa: E402

#: the builder's sampling of a wall face (``projected_wall_quality``'s ``samples``)
SAMPLES = 4


def mesher_queries(ctx):
    """The signed distance, the wall projector and the closed surface's projector as
    ``mesh_transfinite`` sees them (contact cuts included), and a per-face cap mask."""
    from vmesh.geometry.contact_cut import with_cuts
    from vmesh.geometry.projection import wall_projector

    sdf, project = with_cuts(ctx.sdf, wall_projector(ctx.surface, ctx.caps), ctx.blocks.info.get("contact_cuts"))
    on_cap = np.zeros(ctx.surface.n_faces, bool)
    for cap in ctx.caps or []:
        on_cap[np.asarray(cap.faces, np.int64)] = True
    return sdf.fine, project, wall_projector(ctx.surface), on_cap


def flagged_faces(ctx) -> dict:
    """One row per wall face of a flagged block (see the module docstring)."""
    from vmesh.blocks import AXIS_KIND_NAMES, FACE_WALL, HEX_CORNERS, HEX_FACES
    from vmesh.geometry.blocks.checks import _OPPOSITE, _face_quality

    blocks = ctx.blocks
    distance, project, closed, on_cap = mesher_queries(ctx)
    flagged = np.asarray(blocks.info.get("wall_fold_blocks") or [], np.int64)
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    keep = (f < 4) & np.isin(b, flagged)
    b, f = b[keep], f[keep]
    if len(b) == 0:
        return {"faces": []}
    wall = blocks.vertices[blocks.hexes[b[:, None], HEX_FACES[f]]]
    inner = blocks.vertices[blocks.hexes[b[:, None], _OPPOSITE[f]]]
    quality = _face_quality(wall, inner, project, SAMPLES)
    # duplicates: the grid of checks._face_quality, on purpose: the same points the builder judged
    s = np.linspace(0.0, 1.0, SAMPLES + 1)
    U, V = np.meshgrid(s, s, indexing="ij")
    w = np.stack([(1 - U) * (1 - V), U * (1 - V), U * V, (1 - U) * V], axis=-1)
    wall_grid = np.einsum("abc,mcd->mabd", w, wall).reshape(-1, 3)
    inner_grid = np.einsum("abc,mcd->mabd", w, inner).reshape(-1, 3)
    shape = (len(b), SAMPLES + 1, SAMPLES + 1)
    chord = np.asarray(distance.distance(wall_grid)).reshape(shape)
    room = np.asarray(distance.distance(inner_grid)).reshape(shape)
    across = wall_grid - inner_grid
    landed = np.einsum("ij,ij->i", np.asarray(project(wall_grid)) - inner_grid, across) / np.maximum(np.einsum("ij,ij->i", across, across), 1e-300)
    _, _, face = closed.project(wall_grid)
    capped = on_cap[face].reshape(len(b), -1)
    # the face's u axis runs corner 0 -> 1, v corner 0 -> 3 (HEX_FACES order); which block
    # axis each is: the axis whose corner bit differs between the two corners
    corner = HEX_FACES[f]
    u_axis = np.argmax(HEX_CORNERS[corner[:, 1]] != HEX_CORNERS[corner[:, 0]], axis=1)
    v_axis = np.argmax(HEX_CORNERS[corner[:, 3]] != HEX_CORNERS[corner[:, 0]], axis=1)
    deepest = np.argmin(chord.reshape(len(b), -1), axis=1)
    iu, iv = np.unravel_index(deepest, shape[1:])
    # a dip on a u-edge of the face (iu at an end, iv inside) runs between the corners along v,
    # and the other way round; a dip inside both is the face's own ("inside")
    inside_u, inside_v = (iu > 0) & (iu < SAMPLES), (iv > 0) & (iv < SAMPLES)
    kind = blocks.axis_kind[b, np.where(inside_v, v_axis, u_axis)]
    kind = np.where(inside_u & inside_v, -1, np.where(inside_u | inside_v, kind, -2))
    rows = []
    for k in np.argsort(quality, kind="stable"):
        rows.append({"block": int(b[k]), "skeleton_node": int(blocks.block_node[b[k]]), "radius": round(float(blocks.block_radius[b[k]]), 4),
                     "projected_quality": round(float(quality[k]), 4), "layer": round(float(np.linalg.norm(wall[k] - inner[k], axis=1).mean()), 4),
                     "chord_min": round(float(chord[k].min()), 4), "inner_min": round(float(room[k].min()), 4),
                     "landed_min": round(float(landed.reshape(len(b), -1)[k].min()), 3), "dip": {-1: "inside", -2: "corner"}.get(int(kind[k])) or AXIS_KIND_NAMES[int(kind[k])],
                     "on_cap": int(capped[k].sum())})
    return {"faces": rows, "wall_corners_on_cap": int(on_cap[closed.project(np.unique(wall.reshape(-1, 3), axis=0))[2]].sum())}


def main(argv=None) -> int:
    args = prefix_arguments(__doc__.splitlines()[0], "write the rows here").parse_args(argv)
    out = flagged_faces(prefix_context(args.surface, args.skeleton, Path(args.prefix)))
    rows = out["faces"]
    cols = ["block", "skeleton_node", "radius", "projected_quality", "layer", "chord_min", "inner_min", "landed_min", "dip", "on_cap"]
    print(" ".join(f"{c:>11.11s}" for c in cols))
    for r in rows:
        print(" ".join(f"{str(r[c]):>11.11s}" for c in cols))
    folded = [r for r in rows if r["projected_quality"] <= 0]
    print(f"{len(folded)} of {len(rows)} flagged wall faces fold when projected; of those, {sum(r['on_cap'] > 0 for r in folded)} have grid points "
          f"nearest a cap, {sum(r['inner_min'] < 0 for r in folded)} an inner face outside the vessel, {sum(r['landed_min'] < 0 for r in folded)} a "
          f"projected wall beyond the inner face; deepest chord dip along the skeleton in {sum(r['dip'] == 'along' for r in folded)}; "
          f"wall corners on a cap: {out.get('wall_corners_on_cap', 0)}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
