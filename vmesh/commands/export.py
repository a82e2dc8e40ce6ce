"""``vmesh export``: convert a finished run folder's mesh to solver formats or MeshLab layers.

Examples
--------
::

    vmesh export out/y --format msh                 # out/y/mesh.msh (Gmsh 4.1, physical groups)
    vmesh export out/y --format inp,exo,openfoam    # several at once
    vmesh export out/y --format xdmf -o case/vessel.xdmf
    vmesh export out/y --format meshlab             # out/y/meshlab/ with vmesh.mlp
    vmesh export out/y --format openfoam --case steady --to-units m   # a simpleFoam case, SI
"""

from __future__ import annotations

import numpy as np

from pathlib import Path

from ..cli import EXTRA_COMMANDS
from ..errors import ParameterError

HELP = "convert a run folder's mesh: vtu, msh (Gmsh 4.1), inp (Abaqus), exo (Exodus II), mesh (Medit), xdmf, openfoam, meshlab"


def add_arguments(p) -> None:
    from ..io.export import EXPORT_FORMATS

    p.add_argument("run_dir", metavar="RUN_DIR", help="a finished run folder (vmesh run ... -o RUN_DIR)")
    p.add_argument("-f", "--format", required=True, metavar="FMT",
                   help="format name or extension, comma-separated for several: " + ", ".join(EXPORT_FORMATS) + ", meshlab (aliases: msh, inp, exo, mesh)")
    p.add_argument("-o", "--out", metavar="PATH", help="output file or folder (one format only; default RUN_DIR/mesh.<ext>, RUN_DIR/openfoam, RUN_DIR/meshlab)")
    p.add_argument("--linearize", action="store_true", help="write only element corners to formats that cannot hold the mesh order")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.add_argument("--to-units", choices=("m", "cm", "mm", "um"), help="convert lengths from the run's units (report.json 'units') to these")
    p.add_argument("--scale", type=float, metavar="F", help="multiply every coordinate by F instead (units then unknown unless --to-units names them)")
    p.add_argument("--case", choices=("steady", "transient"), help="openfoam: also write 0/, constant/ and system/ for simpleFoam (steady) or pimpleFoam (transient); needs metres")
    p.add_argument("--inlet-velocity", type=float, metavar="U", help="--case: speed into every inlet patch, m/s (default 0.1)")
    p.add_argument("--nu", type=float, metavar="NU", help="--case: kinematic viscosity, m^2/s (default 3.3e-6, blood)")
    p.add_argument("--iterations", type=int, metavar="N", help="--case steady: simpleFoam iterations (default 1000)")
    p.add_argument("--end-time", type=float, metavar="T", help="--case transient: pimpleFoam end time, s (default 1)")


def run(args) -> int:
    from ..io.atomic import check_replaceable
    from ..io.export import default_filename, export_mesh, resolve_format
    from ..io.run_folder import check_run_dir, read_run_mesh

    run_dir = check_run_dir(args.run_dir)
    names = [f.strip() for f in args.format.split(",") if f.strip()]
    if not names:
        raise ParameterError("--format is empty", run_dir)
    if args.out and len(names) > 1:
        raise ParameterError("--out takes one format only", args.out)
    # every format checked, and every order refusal found, before anything is written
    targets = []
    for name in names:
        if name.lower() == "meshlab":
            targets.append(("meshlab", Path(args.out) if args.out else run_dir / "meshlab"))
            continue
        fmt = resolve_format(run_dir, name)
        targets.append((fmt, Path(args.out) if args.out else run_dir / default_filename(fmt)))
    for fmt, path in targets:  # a folder in the way refused now, not after other formats are written
        check_replaceable(path, folder=fmt == "meshlab" or fmt.folder)
    flow = _flow_case(args, run_dir, targets)
    mesh = _in_units(read_run_mesh(run_dir), run_dir, args)
    if flow is not None and mesh.units != "m":
        raise ParameterError(f"an OpenFOAM {flow.kind} case needs lengths in metres, the mesh is in {mesh.units or 'unknown units'}: add --to-units m", run_dir)
    for fmt, path in targets:
        if fmt != "meshlab" and mesh.order > fmt.max_order and not args.linearize:
            export_mesh(path, mesh, fmt.name)  # raises the one-line refusal
    for fmt, path in targets:
        if fmt == "meshlab":
            _export_meshlab(run_dir, mesh, path)
        else:
            export_mesh(path, mesh, fmt.name, linearize=args.linearize, flow=flow if fmt.name == "openfoam" else None)
        if not args.quiet:
            linear = fmt != "meshlab" and args.linearize and mesh.order > fmt.max_order
            nodes = len(np.unique(mesh.corner_cells())) if linear else mesh.n_points
            case = f", {flow.kind} case for {'simpleFoam' if flow.kind == 'steady' else 'pimpleFoam'}" if flow is not None and fmt != "meshlab" and fmt.name == "openfoam" else ""
            print(f"wrote {path}{'/' if path.is_dir() else ''} ({'meshlab' if fmt == 'meshlab' else fmt.name}: {mesh.n_cells} elements, {nodes} nodes, "
                  f"p = {1 if linear else mesh.order}, lengths in {mesh.units or 'unknown units'}{case})")
    return 0


def _flow_case(args, run_dir, targets):
    """The :class:`FlowCase` of ``--case`` (checked before anything is written), or None."""
    from ..io.openfoam_case import FlowCase

    given = {name: value for name, value in (("--inlet-velocity", args.inlet_velocity), ("--nu", args.nu),
                                             ("--iterations", args.iterations), ("--end-time", args.end_time)) if value is not None}
    if args.case is None:
        if given:  # an option that would do nothing is refused, not ignored
            raise ParameterError(f"{', '.join(given)} set(s) up an OpenFOAM flow case: add --case steady|transient --format openfoam", run_dir)
        return None
    if not any(fmt != "meshlab" and fmt.name == "openfoam" for fmt, _ in targets):
        raise ParameterError("--case writes an OpenFOAM case: add --format openfoam", run_dir)
    for name, value in given.items():
        if not value > 0:
            raise ParameterError(f"{name} {value} must be positive", run_dir)
    defaults = FlowCase(kind=args.case)
    pick = lambda value, default: default if value is None else value  # noqa: E731
    return FlowCase(kind=args.case, inlet_velocity=pick(args.inlet_velocity, defaults.inlet_velocity), nu=pick(args.nu, defaults.nu),
                    iterations=pick(args.iterations, defaults.iterations), end_time=pick(args.end_time, defaults.end_time))


def _in_units(mesh, run_dir: Path, args):
    """The run's mesh with its recorded length unit, converted by --to-units / --scale."""
    from ..io.export import convert_units
    from ..io.mesh import units_from_field_data
    from ..io.run_folder import read_report

    import pyvista as pv

    # the VTU's own record first: an export to vtu with --to-units rewrites mesh.vtu
    mesh.units = units_from_field_data(pv.read(str(run_dir / "mesh.vtu")).field_data) or read_report(run_dir).get("units", {}).get("length")
    try:
        return convert_units(mesh, args.to_units, args.scale)
    except ParameterError as exc:
        raise ParameterError(exc.problem, run_dir) from None


def _export_meshlab(run_dir: Path, mesh, path: Path) -> None:
    from ..io.meshlab import write_meshlab_folder
    from ..io.run_folder import run_surface_path
    from ..io.skeleton import read_skeleton
    from ..io.surface import read_surface

    surfaces = {}
    for layer in ("surface", "coarse_surface"):
        p = run_surface_path(run_dir, layer)
        surfaces[layer] = read_surface(p) if p is not None else None
    skeleton = read_skeleton(run_dir / "skeleton.json") if (run_dir / "skeleton.json").is_file() else None
    edges = run_dir / "blocks_edges.ply"
    write_meshlab_folder(path, mesh, surfaces["surface"], surfaces["coarse_surface"], skeleton, edges if edges.is_file() else None)


EXTRA_COMMANDS["export"] = (add_arguments, run, HELP)
