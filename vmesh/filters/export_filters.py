"""Export filters: solver formats (Gmsh, Abaqus, Exodus II, Medit, XDMF, OpenFOAM, VTU) and
the MeshLab layer set. Thin wrappers around :mod:`vmesh.io.export` and
:mod:`vmesh.io.meshlab`."""

from __future__ import annotations

from ..errors import ParameterError
from ..registry import Parameter, register_filter

_FORMATS = ("auto", "vtu", "gmsh", "abaqus", "exodus", "medit", "xdmf", "openfoam")


@register_filter(
    description="Write the mesh for a solver: VTU, Gmsh 4.1 .msh, Abaqus .inp, Exodus II, Medit .mesh, XDMF or an OpenFOAM case, with label and wall/inlet/outlet groups.",
    parameters=[
        Parameter("filename", "str", "mesh.msh", "File name in the output folder (a folder for OpenFOAM); its extension picks the format when format = auto (.vtu .msh .inp .exo .mesh .xdmf)."),
        Parameter("format", "str", "auto", "Format; auto takes it from the file name's extension.", choices=_FORMATS),
        Parameter("linearize", "bool", False, "For a format that cannot hold the mesh order (OpenFOAM, Abaqus, Exodus, Medit above p = 1; XDMF above 2), write the element corners only instead of failing."),
    ],
    reads=("mesh",),
    category="export",
)
def export_mesh(ctx, filename, format, linearize):
    """Element labels become Gmsh 3D physical groups, Abaqus element sets, Exodus element
    blocks, Medit references and XDMF cell arrays; the wall and each inlet/outlet become
    Gmsh 2D physical groups, Abaqus surfaces and node sets, Exodus side and node sets, Medit
    quadrilateral references and OpenFOAM patches. p = 2 goes to Gmsh as hex27 and to
    VTU as Lagrange hexahedra."""
    from ..io.export import export_mesh as export, resolve_format

    fmt = None if format == "auto" else format
    resolve_format(filename, fmt)  # unknown extensions fail before any work
    path = ctx.output_file(filename)
    if path is None:
        return
    f = resolve_format(path, fmt)
    if ctx.mesh.order > f.max_order and not linearize:
        raise ParameterError(
            f"filter 'export_mesh': {f.name} holds hexahedra of order p <= {f.max_order}, the mesh has p = {ctx.mesh.order} "
            "(set linearize = true to write the corners only)"
        )
    export(path, ctx.mesh, fmt, linearize=linearize)
    ctx.count(format=f.name, elements=ctx.mesh.n_cells, nodes=ctx.mesh.n_points)


def _check_project_name(project):
    if not project.lower().endswith(".mlp"):
        raise ParameterError(f"filter 'export_meshlab': parameter 'project' must end in .mlp, got {project!r}")


@register_filter(
    description="Write the MeshLab layers: input and coarse surfaces, the mesh boundary as quads coloured by label and by scaled Jacobian, skeleton and block edges as edge meshes, and a .mlp project.",
    parameters=[
        Parameter("folder", "str", "meshlab", "Folder in the output folder that receives the layers and the project."),
        Parameter("project", "str", "vmesh.mlp", "MeshLab project file name (inside folder)."),
    ],
    reads=("mesh",),
    optional_reads=("surface", "coarse_surface", "skeleton", "blocks"),
    category="export",
    check=lambda params: _check_project_name(params["project"]),
)
def export_meshlab(ctx, folder, project):
    """The boundary PLYs carry per-face colour and per-face quality (boundary id, or the
    owning element's scaled Jacobian for MeshLab's Quality Mapper); high-order faces are
    split into p x p quads. The project opens every layer; ``vmesh render`` and
    ``vmesh export --format meshlab`` reuse the surfaces written here."""
    from ..io.meshlab import write_meshlab_folder

    path = ctx.output_file(folder)
    if path is None:
        return
    edges = None
    if ctx.blocks is not None:
        from .block_filters import block_edges

        edges = (ctx.blocks.vertices, block_edges(ctx.blocks)[0])
    written = write_meshlab_folder(path, ctx.mesh, ctx.surface, ctx.coarse_surface, ctx.skeleton, edges, project=project)
    ctx.count(layers=written["project"]["layers"])
