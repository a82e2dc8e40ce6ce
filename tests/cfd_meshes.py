"""Small hexahedral meshes for the CFD tests, built without a full chain: the hand-built
O-grid cylinder of :mod:`cylinder_blocks` meshed by the transfinite stage alone."""

import numpy as np

from cylinder_blocks import cylinder_blocks, project_cylinder
from vmesh.context import Context
from vmesh.geometry.boundary_layer import setup_boundary_layer
from vmesh.geometry.transfinite import Refinement, mesh_blocks
from vmesh.io.names import label_names
from vmesh.mesh import HexMesh

RADIUS = 2.0


def layer_params(**given) -> dict:
    """mesh_transfinite's boundary-layer parameters at their defaults, overridden by ``given``."""
    params = dict(refinement=1, elements_layer=3, grading="first_layer", first_layer=0.02, growth=1.3, first_layer_height="",
                  boundary_layer_thickness="", y_plus=0.0, flow_velocity=0.5, flow_density=1060.0, flow_viscosity=3.5e-3, reference_length="")
    params.update(given)
    return params


def cylinder_mesh(units="mm", sections=3, length=10.0, tags=None, **given):
    """(mesh, context) of a cylinder of radius 2 along z (inlet at z = 0, outlet_1 at
    z = length) meshed with the boundary-layer parameters ``given``; ``tags``: the skeleton
    tags of each block section (list of tuples, one per section)."""
    blocks = cylinder_blocks(radius=RADIUS, length=length, sections=sections)
    if tags is not None:
        blocks.block_tags = [tuple(tags[s]) for s in blocks.block_segment]
    ctx = Context(inputs={"units": units})
    ctx.blocks = blocks
    layer = setup_boundary_layer(ctx, **layer_params(**given))
    ref = Refinement(around=2, core=2, ring=2, element_length=1.0, **layer)
    sm = mesh_blocks(ctx.blocks, project_cylinder(RADIUS), ref)
    b = sm.cell_block
    names = label_names(ctx.blocks.block_tags, ctx.blocks.boundary_names.values())
    unique = sorted(set(names))
    block_label = np.array([unique.index(n) for n in names])
    mesh = HexMesh(
        points=sm.points, cells=sm.cells, order=1,
        cell_data={"block_id": b.astype(np.int64), "layer": ctx.blocks.block_layer[b], "label": block_label[b]},
        boundary_faces=sm.boundary_faces, boundary_ids=sm.boundary_ids, boundary_cells=sm.boundary_cells,
        boundary_names=dict(ctx.blocks.boundary_names), label_names=dict(enumerate(unique)), units=units,
    )
    return mesh, ctx
