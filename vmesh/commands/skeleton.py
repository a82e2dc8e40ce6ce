"""``vmesh skeleton``: read or extract a skeleton, clean, resample and tag it, write it and
a PNG render of it over the transparent surface.

Examples
--------
::

    vmesh skeleton vessel.stl --out skel.json                 # extract, clean, write + skel.png
    vmesh skeleton vessel.vtp --skeleton centerlines.vtp --spacing 1.5 --out coarse.vtp
    vmesh skeleton centerline.swc --out centerline.json        # convert (no surface)
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..cli import EXTRA_COMMANDS, parse_overrides
from ..errors import InputError

HELP = "read or extract a centerline skeleton, clean/resample/tag it, write it and a PNG render"

#: Suffixes that can only be skeletons.
_SKELETON_ONLY = (".json", ".swc", ".csv")


def add_arguments(p) -> None:
    p.add_argument("input", metavar="INPUT", help="vessel surface (stl, obj, ply, vtp, vtk, vtu, off), or a centerline file to convert")
    p.add_argument("-s", "--skeleton", metavar="FILE", help="centerline file (json, swc, csv, ply, vtp, vtk); extracted from the surface when absent")
    p.add_argument("-o", "--out", metavar="FILE", help="write the skeleton here; the extension picks the format (json, swc, csv, ply, vtp, vtk; a .vtp/.vtk holds one polyline per branch with a Radius point array, not VMTK's overlapping inlet-to-outlet lines)")
    p.add_argument("--png", metavar="FILE", help="render to this PNG (default: --out with the suffix .png)")
    p.add_argument("--no-png", action="store_true", help="do not render a PNG")
    p.add_argument("--vtk-kind", default="auto", choices=("auto", "vmtk", "simvascular", "polylines"), help="what a .vtp/.vtk centerline holds (default: auto)")
    p.add_argument("--no-clean", action="store_true", help="skip clean_skeleton")
    p.add_argument("--spacing", type=float, metavar="X", help="resample with nodes X local radii apart (resample_skeleton)")
    p.add_argument("--radius-change", type=float, metavar="G", help="with --spacing: extra nodes where |dr/ds| > G (0: none)")
    p.add_argument("--tag-branches", action="store_true", help="tag branch_<k> on every branch")
    p.add_argument("--sac-ratio", type=float, metavar="R", help="tag nodes wider than R x their parent branch as 'aneurysm'")
    p.add_argument("--set", action="append", metavar="FILTER.PARAM=VALUE", help="override a filter parameter (repeatable)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def _registered(name: str) -> bool:
    from ..registry import filter_list

    return name in filter_list()


def _is_skeleton_file(path: Path) -> bool:
    """Whether ``path`` holds a centerline rather than a surface."""
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in _SKELETON_ONLY:
        return True
    if not path.is_file():
        return False
    if suffix == ".ply":
        head = path.read_bytes()[:4096]
        return b"element edge" in head and b"element face" not in head
    if suffix in (".vtp", ".vtk"):
        from ..io.skeleton_formats import _load_vtk

        try:
            mesh = _load_vtk(path)
        except Exception:
            return False  # let the surface reader report the problem
        return mesh.n_lines > 0 and mesh.n_cells == mesh.n_lines + mesh.n_verts
    return False


#: the command's options that set a filter parameter: (option, attribute, filter, parameter)
OPTION_PARAMETERS = (
    ("--spacing", "spacing", "resample_skeleton", "spacing"),
    ("--radius-change", "radius_change", "resample_skeleton", "radius_change"),
    ("--sac-ratio", "sac_ratio", "tag_skeleton", "sac_ratio"),
)


def _check_options(args) -> None:
    """Refuse an option's value its filter parameter refuses, naming the option (not the
    chain step the command builds from it)."""
    from ..errors import ParameterError
    from ..registry import get_filter

    for option, attr, fname, pname in OPTION_PARAMETERS:
        value = getattr(args, attr, None)
        if value is None or not _registered(fname):
            continue
        try:
            get_filter(fname).parameter(pname).validate(value, f"filter '{fname}'")
        except ParameterError as exc:
            raise InputError(f"{option} {value:g}: {exc}") from None


def build_chain(args, surface_open: bool, has_surface: bool, has_skeleton: bool, inlet_point=None):
    """The filter chain the command runs, from its options (the skeleton, when given, is
    read before the chain runs so that a bad file fails before any work).

    The surface is repaired first (as in the default chain); open surfaces are capped,
    closed ones get their flat caps detected, so that the skeleton's ends can be put on
    the caps; ``inlet_point`` (the centerline's inlet)
    names the cap nearest to it the inlet.
    """
    from ..chain import FilterChain

    _check_options(args)
    chain = FilterChain(name="skeleton", description="vmesh skeleton command")
    if has_surface and _registered("repair_surface"):
        # as `vmesh run default`: weld, drop degenerate faces and stray pieces, orient
        # consistently (capping and the signed distance need it)
        chain.append("repair_surface")
    need_sdf = has_surface and (not has_skeleton or not args.no_clean) and _registered("build_sdf")
    caps_filter = "cap_open_ends" if surface_open else ("detect_caps" if not args.no_clean else None)
    if has_surface and caps_filter and _registered(caps_filter):
        chain.append(caps_filter, {} if inlet_point is None else {"inlet_point": [float(x) for x in inlet_point]})
    if need_sdf:
        chain.append("build_sdf")
    if not has_skeleton:
        if not has_surface:
            raise InputError("no surface and no skeleton given", args.input)
        if not _registered("extract_skeleton"):
            raise InputError("no --skeleton given and skeleton extraction (extract_skeleton) is not available", args.input)
        chain.append("extract_skeleton")
    elif need_sdf:
        chain.append("estimate_radii")
    if not args.no_clean:
        chain.append("clean_skeleton", {} if need_sdf else {"outside": "keep"})
    if args.spacing is not None:
        params = {"spacing": args.spacing}
        if args.radius_change is not None:
            params["radius_change"] = args.radius_change
        chain.append("resample_skeleton", params)
    if args.tag_branches or args.sac_ratio is not None:
        params = {"branches": bool(args.tag_branches)}
        if args.sac_ratio is not None:
            params["sac_ratio"] = args.sac_ratio
        chain.append("tag_skeleton", params)
    return chain


def summary_text(skeleton) -> str:
    import numpy as np

    s = skeleton.summary()
    r = skeleton.radii[np.isfinite(skeleton.radii)]
    lines = [
        f"skeleton   {skeleton.name}",
        f"nodes      {s['nodes']}",
        f"segments   {s['segments']}",
        f"junctions  {s['junctions']} (max degree {s['max_degree']})",
        f"endpoints  {s['endpoints']}",
        f"cycles     {s['cycles']}",
        f"components {s['components']}",
        "radius     " + (f"{r.min():.4g} .. {r.max():.4g} (median {np.median(r):.4g})" if len(r) else "unknown"),
        f"tags       {', '.join(skeleton.tag_names()) or '-'}",
    ]
    if len(r) < skeleton.n_nodes:
        lines.append(f"           {skeleton.n_nodes - len(r)} nodes without radius")
    return "\n".join(lines)


def run(args) -> int:
    from ..io.skeleton import SKELETON_WRITERS, write_skeleton
    from ..io.surface import read_surface

    source = Path(args.input)
    if not source.exists():
        raise InputError("file not found", source)
    skeleton_path = args.skeleton
    surface = None
    if _is_skeleton_file(source):
        if skeleton_path is not None:
            raise InputError("INPUT is a centerline; give the surface as INPUT and the centerline with --skeleton", source)
        skeleton_path = str(source)
    else:
        notes: list[str] = []
        surface = read_surface(source, notes)
        for note in notes:  # what reading changed (a volume mesh's boundary, stray cells dropped)
            print(f"warning: {note}", file=sys.stderr)
    if args.out and Path(args.out).suffix.lower() not in SKELETON_WRITERS:
        raise InputError(f"unknown skeleton format '{Path(args.out).suffix}' (supported: {', '.join(sorted(SKELETON_WRITERS))})", args.out)
    if args.png and Path(args.png).suffix.lower() != ".png":
        raise InputError("--png needs a .png file name", args.png)
    skeleton = None
    if skeleton_path is not None:
        from ..io.skeleton import read_skeleton

        kind = Path(skeleton_path).suffix.lower() in (".vtp", ".vtk")
        skeleton = read_skeleton(skeleton_path, **({"kind": args.vtk_kind} if kind else {}))
    surface_open = surface is not None and surface.info().n_boundary_loops > 0
    inlet = None
    if skeleton is not None:
        tagged = [i for i in skeleton.endpoints.tolist() if "inlet" in skeleton.node_tags[i]]
        inlet = skeleton.points[tagged[0]] if tagged else None
    chain = build_chain(args, surface_open, surface is not None, skeleton is not None, inlet)
    chain = chain.with_overrides(parse_overrides(args.set))
    if not chain.steps:
        from ..context import Context

        ctx = Context(surface=surface, skeleton=skeleton)
    else:
        ctx = chain.run(surface=surface, skeleton=skeleton, progress=not args.quiet)
    skeleton = ctx.skeleton
    print(summary_text(skeleton))
    if not args.quiet and chain.steps:
        print()
        print(ctx.report.summary_table())
    for w in ctx.report.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.out:
        write_skeleton(args.out, skeleton)
        print(f"wrote {args.out}")
    png = args.png or (str(Path(args.out).with_suffix(".png")) if args.out else None)
    if png and not args.no_png:
        from ..filters.skeleton_filters import render_skeleton_png

        try:
            render_skeleton_png(png, skeleton, ctx.surface)
            print(f"wrote {png}")
        except Exception as exc:  # no OpenGL context: the skeleton is still written
            print(f"warning: could not render {png}: {' '.join(str(exc).split())[:160] or 'no picture'}", file=sys.stderr)
    return 0


EXTRA_COMMANDS["skeleton"] = (add_arguments, run, HELP)
