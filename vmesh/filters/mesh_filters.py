"""Meshing filters: transfinite hexahedra, element labels, quality, mesh output."""

from __future__ import annotations

import numpy as np

from ..errors import MeshingError
from ..geometry.coverage import DEPTH, DISTANCE, END_DEPTH, PATCH_AREA
from ..registry import Parameter, register_filter


@register_filter(
    description="Fill every block with hexahedra by transfinite maps (graded boundary layer, order p = 1..4).",
    parameters=[
        Parameter("refinement", "int", 1, "Multiplies every element count below (1 = as given).", min=1, max=16),
        Parameter("elements_around", "int", 2, "Elements per block edge around the circumference (and across core blocks).", min=1, max=64),
        Parameter("elements_ring", "int", 2, "Elements radially across the ring between core and boundary layer.", min=1, max=64),
        Parameter("elements_layer", "int", 3, "Elements radially across the boundary-layer blocks; 0 = derived from first_layer_height, growth (grading = growth) and the layer thickness.", min=0, max=64),
        Parameter("element_length", "float", 0.5, "Element length along the skeleton, relative to the local radius (divided by refinement).", unit="× radius", min=0.01, max=20.0),
        Parameter("grading", "str", "first_layer", "Boundary-layer node distribution: uniform, first_layer (first element thickness given) or growth (ratio given).", choices=("uniform", "first_layer", "growth")),
        Parameter("first_layer", "float", 0.02, "First boundary-layer element thickness relative to the local radius (grading = first_layer).", unit="× radius", min=1e-5, max=1.0),
        Parameter("growth", "float", 1.3, "Ratio of consecutive boundary-layer element thicknesses (grading = growth).", min=1.0, max=10.0),
        Parameter("first_layer_height", "length", "", "Absolute first boundary-layer element height, a length with its unit ('0.05mm', '50um'; no unit = the input's units); replaces first_layer; '' = not set (first_layer, or y_plus when on, gives the height). Any three of first-layer height, boundary_layer_thickness, elements_layer and growth (grading = growth; uniform = 1) fix the fourth (docs/cfd.md)."),
        Parameter("boundary_layer_thickness", "length", "", "Absolute total thickness of the boundary-layer blocks ('0.6mm'); '' = the block structure's (build_block_structure.layer_thickness × wall distance)."),
        Parameter("y_plus", "float", 0.0, "Target y+ of the first element: sets first_layer_height from the flat-plate skin friction Cf = 0.026 Re^(-1/7) with flow_velocity, flow_density, flow_viscosity and reference_length (0 = off).", min=0.0, max=1000.0),
        Parameter("flow_velocity", "float", 0.5, "Bulk velocity for the y+ estimate.", unit="m/s", min=1e-9, max=1e3),
        Parameter("flow_density", "float", 1060.0, "Fluid density for the y+ estimate (blood: 1060).", unit="kg/m³", min=1e-6, max=1e5),
        Parameter("flow_viscosity", "float", 3.5e-3, "Dynamic viscosity for the y+ estimate (blood: 3.5e-3).", unit="Pa·s", min=1e-9, max=1e3),
        Parameter("reference_length", "length", "", "Length of the Reynolds number of the y+ estimate ('25mm'); '' = the widest vessel diameter (twice the largest block radius)."),
        Parameter("order", "int", 1, "Mesh order p: 1 linear hexahedra, 2..4 Lagrange hexahedra.", min=1, max=4),
        Parameter("node_distribution", "str", "gauss_lobatto", "High-order node positions inside each element.", choices=("gauss_lobatto", "equispaced")),
        Parameter("project_to", "str", "fine", "Surface the wall nodes are projected onto: the fine (input) or the coarse surface.", choices=("fine", "coarse")),
        Parameter("untangle", "bool", True, "Move the nodes around elements of low scaled Jacobian (folds at junction crotches) to make them valid: wall nodes slide on the wall, cap nodes in the cap plane."),
        Parameter("untangle_below", "float", 0.3, "Elements whose scaled Jacobian is below this are optimised with their neighbourhood (p > 1: of the element corners with optimiser = local, of the sub-hexahedra with lbfgs).", min=0.0, max=0.9),
        Parameter("untangle_restart_below", "float", 0.3, "When untangling leaves an element below this, untangle once more from its result (fresh targets) and keep the better; with optimiser = local: the L-BFGS untangler also runs when the local result's minimum is not above this; 0 = never.", min=0.0, max=0.9),
        Parameter("optimiser", "str", "local", "local: compiled per-node Newton steps around bad elements, Gauss-Seidel over a node colouring (vmesh.geometry.optimize); lbfgs: the former global L-BFGS untangler.", choices=("local", "lbfgs")),
        Parameter("light_pass_below", "float", 0.95, "Light pass after untangling (optimiser = local; untangle = true): every node of an element below this takes monotone Newton steps (its elements' minimum and mean scaled Jacobian never drop; wall nodes slide on the wall, first boundary-layer heights kept); for p > 1 kept only when the order-p minimum does not drop and the mean rises; for p = 1 on a mesh still inverted after untangling, kept only when its minimum does not drop (report.json: light_pass.refused); 0 = off (docs/optimiser.md).", min=0.0, max=1.0),
        Parameter("light_pass_sweeps", "int", 8, "Most Gauss–Seidel sweeps of the light pass (4 give most of the gain at less cost; with light_pass_over_relax=1.5, 6 reach what 8 plain ones do on the ICA).", min=1, max=100),
        Parameter("light_pass_over_relax", "float", 1.0, "Light pass and the untanglers' smoothing phase: a smoothing Newton step (not a wall node's) is first tried this many times longer, then 1, 1/2, ... (over-relaxed Gauss-Seidel: fewer sweeps for the same gain; 1 = plain; docs/optimiser.md).", min=1.0, max=2.0),
        Parameter("light_pass_tol", "float", 0.01, "Light pass: a node that moves less than this fraction of half its longest edge does not send its neighbours back to work (converged regions stop early; 0 = every move does; docs/speed.md).", min=0.0, max=0.5),
        Parameter("light_pass_ratio_floor", "float", 0.3, "Light and worst passes: a step may not lower the Jacobian ratio (min / max det J over the corners) of any element the node touches below the lesser of this and the least ratio of those elements before the step, so the passes do not taper the boundary layer (the corner scaled Jacobian they climb does not see an element thinning at one edge); the worst pass's max-min direction keeps the ratio of an element at that limit from falling; 0 = no guard; 0.3 removes the taper (docs/optimiser.md). The untanglers' smooth_below phase is not guarded.", min=0.0, max=1.0),
        Parameter("curved_sections", "bool", True, "Curve the core/ring and ring/boundary-layer interfaces of the cross-sections so that the element angles at their corners balance (120° at core corners instead of 90°/135°/135°; docs/optimiser.md)."),
        Parameter("smooth_below", "float", 0.5, "Light pass after untangling (optimiser = local): nodes of elements below this move only where their elements' minimum and mean scaled Jacobian do not drop; 0 = off.", min=0.0, max=0.95),
        Parameter("worst_pass_sweeps", "int", 60, "After the light pass, only with untangle = true, optimiser = local and light_pass_below > 0 (p = 1, a valid mesh): the nodes of elements still below smooth_below (its threshold) take max-min steps judged by their worst incident element alone (wall nodes on the wall, first boundary-layer heights kept), then the light pass runs again; most sweeps, 0 = off (docs/optimiser.md).", min=0, max=200),
        Parameter("exact_first_layer", "bool", True, "With first_layer_height (or y_plus): after the optimisers (untangling and the light pass), re-place the nodes of every boundary-layer line so that the first element is that height along the wall normal; with boundary_layer_thickness: before untangling, put the layer's inner nodes at that thickness along the wall normal (docs/cfd.md)."),
    ],
    reads=("blocks", "surface"),
    optional_reads=("coarse_surface", "caps", "skeleton", "sdf"),
    writes=("mesh",),
    category="meshing",
)
def mesh_transfinite(ctx, refinement, elements_around, elements_ring, elements_layer, element_length, grading, first_layer, growth,
                     first_layer_height, boundary_layer_thickness, y_plus, flow_velocity, flow_density, flow_viscosity, reference_length,
                     order, node_distribution, project_to, untangle, untangle_below, untangle_restart_below,
                     optimiser="local", smooth_below=0.5, curved_sections=True, light_pass_below=0.95, light_pass_sweeps=8,
                     exact_first_layer=True, light_pass_tol=0.01, worst_pass_sweeps=60, light_pass_ratio_floor=0.3, light_pass_over_relax=1.0):
    """Edge nodes are projected onto the wall and re-spaced by arc length; Coons patches fill
    block faces (wall faces projected again) and transfinite interpolation fills the blocks.
    The boundary layer is resolved by grading, never by extra element layers: the element
    count is the same with and without grading."""
    from ..geometry.blocks.stubs import meshed_as_wall, name_stub_faces
    from ..geometry.boundary_layer import record_first_layer, setup_boundary_layer
    from ..geometry.projection import caps_on, wall_projector
    from ..geometry.transfinite import Refinement, mesh_blocks
    from ..mesh import HexMesh

    layer = setup_boundary_layer(ctx, refinement, elements_layer, grading, first_layer, growth, first_layer_height, boundary_layer_thickness,
                                 y_plus, flow_velocity, flow_density, flow_viscosity, reference_length)
    surface = ctx.coarse_surface if project_to == "coarse" and ctx.coarse_surface is not None else ctx.surface
    caps = caps_on(surface, ctx.surface, ctx.caps)  # the coarse surface's own cap triangles: kept caps stay kept
    projector = wall_projector(surface, caps, kept=ctx.blocks.info.get("touched_caps", ()))  # as the builder's checks
    ref = Refinement(
        around=elements_around * refinement,
        core=elements_around * refinement,
        ring=elements_ring * refinement,
        element_length=element_length / refinement,
        order=order,
        nodes=node_distribution,
        curved_sections=curved_sections,
        **layer,
    )
    named = ctx.blocks
    blocks = meshed_as_wall(named)  # a cut stub's mouth is meshed as the wall it continues, named after
    sdf = ctx.sdf if ctx.sdf is not None and ctx.sdf.n_faces == surface.n_faces else None
    if sdf is None:
        from ..geometry.sdf import SignedDistance

        sdf = SignedDistance.from_surface(surface)
    # the mesher queries near the wall only, where the exact fine query is cheaper than a
    # coarse query plus its refinement
    cuts = blocks.info.get("contact_cuts")
    if cuts is not None:  # the domain the blocks were built in (vmesh.geometry.contact_cut)
        from ..geometry.contact_cut import with_cuts

        sdf, projector = with_cuts(sdf, projector, cuts)
    exact = sdf.fine
    sm = mesh_blocks(blocks, projector, ref, progress=ctx.tick, signed_distance=exact.distance, intersect_lines=exact.intersect_lines)
    if exact_first_layer:  # a given layer thickness, from the wall rather than the block corners
        from ..geometry.boundary_layer import offset_to_thickness

        offset_to_thickness(ctx, sm, blocks, node_distribution)
    ratio_floor = light_pass_ratio_floor if light_pass_ratio_floor > 0 else -np.inf  # 0: no guard
    if untangle:
        _untangle(ctx, sm, projector, sdf, untangle_below, untangle_restart_below, optimiser, smooth_below, node_distribution, light_pass_over_relax)
        if optimiser == "local" and light_pass_below > 0:
            _light_pass(ctx, sm, projector, sdf, light_pass_below, node_distribution, light_pass_sweeps, light_pass_tol, ratio_floor=ratio_floor, over_relax=light_pass_over_relax)
        # the max-min steps let better elements give way: only with the light pass on, which
        # then restores the mean (it never lowers an element's neighbourhood minimum)
        if optimiser == "local" and light_pass_below > 0 and worst_pass_sweeps > 0 and smooth_below > 0:
            lifted = _worst_pass(ctx, sm, projector, sdf, smooth_below, worst_pass_sweeps, ratio_floor)
        else:
            lifted = False
        if lifted:
            _light_pass(ctx, sm, projector, sdf, light_pass_below, node_distribution, light_pass_sweeps, light_pass_tol, name="light_pass_after_worst", ratio_floor=ratio_floor, over_relax=light_pass_over_relax)
    if exact_first_layer and layer["first_layer_absolute"]:  # after the optimisers, which move layer nodes
        from ..geometry.boundary_layer import exact_first_layer as place_first_layer

        place_first_layer(ctx, sm, blocks, layer["first_layer"], node_distribution)
    b = sm.cell_block
    mesh = HexMesh(
        points=sm.points,
        cells=sm.cells,
        order=order,
        cell_data={
            "block_id": b.astype(np.int64),
            "segment_id": blocks.block_segment[b],
            "node_id": blocks.block_node[b],
            "layer": blocks.block_layer[b],
        },
        boundary_faces=sm.boundary_faces,
        boundary_ids=name_stub_faces(named, sm.boundary_ids, sm.boundary_cells, b, sm.boundary_local_face),
        boundary_cells=sm.boundary_cells,
        boundary_names=dict(blocks.boundary_names),
        on_wall=sm.on_wall,
        node_distribution=node_distribution,
        units=ctx.report.sections["units"]["length"],
    )
    record_first_layer(ctx, mesh, ctx.report.sections["boundary_layer"]["target_first_height"])
    ctx.mesh = mesh
    ctx.count(elements=mesh.n_cells, nodes=mesh.n_points)
    ctx.report.counts.update(elements=mesh.n_cells, nodes=mesh.n_points, blocks=blocks.n_blocks)
    ctx.report.sections["order"] = order


def _constraints(sm):
    """Cap nodes with their cap normals, wall nodes and boundary nodes of a structured mesh."""
    n = len(sm.points)
    cap_nodes = np.zeros(n, bool)
    cap_normals = np.zeros((n, 3))
    p = sm.order
    corners = sm.boundary_faces[:, [0, p, (p + 1) ** 2 - 1, p * (p + 1)]]
    for bid in np.unique(sm.boundary_ids[sm.boundary_ids > 0]):
        sel = sm.boundary_ids == bid
        q = sm.points[corners[sel]]
        normal = np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]).sum(axis=0)
        ids = np.unique(sm.boundary_faces[sel])
        cap_nodes[ids] = True
        cap_normals[ids] = normal / max(np.linalg.norm(normal), 1e-300)
    boundary = np.zeros(n, bool)
    boundary[sm.boundary_faces.ravel()] = True
    return cap_nodes, cap_normals, sm.on_wall.copy(), boundary


def _untangle(ctx, sm, projector, sdf, below, restart_below, optimiser="local", smooth_below=0.5, node_distribution="gauss_lobatto", over_relax=1.0):
    """Optimise the nodes around low-quality elements in place (see :mod:`vmesh.geometry.optimize`
    and, for ``optimiser = lbfgs``, :mod:`vmesh.geometry.untangle`)."""

    p = sm.order
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    ctx.tick(0.95, "untangling")
    from ..geometry.quality import scaled_jacobian
    from ..geometry.transfinite import reference_points

    ref_nodes = reference_points(p, node_distribution)
    local = None
    if optimiser == "local":
        from ..geometry.optimize import optimise

        X, info = optimise(
            sm.points, sm.cells, p, ref_nodes=ref_nodes, wall=wall, wall_normals=sdf.gradient, project=projector, cap_nodes=cap_nodes, cap_normals=cap_normals,
            boundary=boundary, untangle_below=below, smooth_below=smooth_below, over_relax=over_relax,
        )
        # the local optimiser is fast but moves few nodes; where it leaves a fold or an element
        # below restart_below (a junction fold that needs a wider region, or an order-p element
        # folded by the nodes that follow the corners), the global untangler runs too. For
        # p = 1 the optimiser's own "after" is the mesh's scaled Jacobian. Its second try with
        # the first boundary-layer nodes free (``free_layer``) is a fallback like the global
        # one: both run and the better is kept.
        local_min = info["after"]["min"] if p == 1 else float(scaled_jacobian(X, sm.cells, p, ref_nodes).min())
        if local_min > max(restart_below or 0.0, 0.0) and not info.get("free_layer", {}).get("kept"):
            _keep_untangled(ctx, sm, X, info, info["moved"], untangled_nodes=info["untangled_nodes"], smoothed_nodes=info["smoothed_nodes"])
            return
        local = (X, info, local_min)
    from ..geometry.untangle import untangle

    # from the unoptimised mesh (its own targets), then the better of the two results is kept
    X, info = untangle(
        sm.points, sm.cells, p, wall=wall, wall_normals=sdf.gradient, project=projector, cap_normals=cap_normals, cap_nodes=cap_nodes, threshold=below,
        boundary=boundary, restart_below=restart_below or None,
    )
    constraints = dict(wall=wall, wall_normals=sdf.gradient, project=projector, cap_nodes=cap_nodes, cap_normals=cap_normals, boundary=boundary)
    if local is not None and scaled_jacobian(X, sm.cells, p, ref_nodes).min() < local[2]:
        held = {"lbfgs_" + k: info[k] for k in ("keep_valid", "keep_valid_reruns") if k in info}  # what the L-BFGS untangler held
        X, info = local[0], {**local[1], "lbfgs_tried": True, **held}
        X = _polish(X, sm, info, (below, smooth_below), constraints)
        _keep_untangled(ctx, sm, X, info, info["moved"], untangled_nodes=info["untangled_nodes"], smoothed_nodes=info["smoothed_nodes"])
        return
    if local is not None:
        info["after_local_min"] = local[2]
    X = _polish(X, sm, info, (below, smooth_below), constraints)
    _keep_untangled(ctx, sm, X, info, info["rounds"], untangled_nodes=info["moved"])


def _polish(X, sm, info, goals, constraints):
    """Where the untanglers leave a valid linear mesh below the untangling goal, climb its
    worst elements with :func:`vmesh.geometry.optimize.polish` (kept only where the minimum
    rises); its report goes to ``info["polish"]`` and ``info["after"]`` follows it.

    The climb's region may grow over as many nodes as the untangler moved (``info["moved"]``,
    at least the optimiser's default 1 % of the nodes): a wide fold leaves its worst elements
    balanced against each other over the whole region it was untangled in, and 1 % of the
    mesh is then too small a region to lift them (sv_rpa given: 6,640 nodes untangled, the
    climb stopped at 0.287 within 1 %, 0.347 within the untangled region's size)."""
    from ..geometry.optimize import polish

    if sm.order != 1:
        return X
    fraction = max(0.01, int(info.get("moved", 0)) / max(len(X), 1))
    Y, report = polish(X, sm.cells, [g for g in goals if g > 0], max_fraction=fraction, **constraints)
    if report["tries"]:
        info["polish"] = report
        info["after"] = report["after"]
    return Y


#: Rings the light pass's untangling of elements the untanglers left inverted may grow
#: without fewer inverted elements or a higher minimum (it is a last local try, after the
#: untanglers). Measured on a fold no ring opens (two vessels fused across each other): it
#: stops after 3 such rings at the same minimum the unbounded growth (63 rings) reached.
#: Safe: a ring that improves either resets the count, and a fold the first rings open
#: grows as without it.
LIGHT_PASS_PATIENCE = 3


def _light_pass(ctx, sm, projector, sdf, below, node_distribution, sweeps=8, tol=0.0, name="light_pass", ratio_floor=-np.inf, over_relax=1.0):
    """The default light pass of :mod:`vmesh.geometry.optimize` over every element below
    ``below``: raises the mean without lowering any element's neighbourhood minimum (its
    untangling threshold is 0, so on a valid mesh nothing is untangled; on an inverted one
    the optimiser's own untangling runs on the inverted elements, bounded by
    :data:`LIGHT_PASS_PATIENCE`). For p > 1 the corners move and the other nodes follow, which
    can lower the order-p quality: the result is kept only when it does not; for p = 1 on an
    inverted mesh it is kept only when the minimum does not drop (the report's ``refused``,
    ``refused_after``). ``name``: its report section
    (and ``<name>_nodes`` count); ``ratio_floor``: the Jacobian-ratio guard of its steps
    (``optimise_linear``; ``-inf`` = none); ``over_relax``: its steps' first trial length."""
    from ..geometry.optimize import optimise
    from ..geometry.quality import scaled_jacobian
    from ..geometry.transfinite import reference_points

    p = sm.order
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    ref_nodes = reference_points(p, node_distribution)
    ctx.tick(0.97, name.replace("_", " "))
    X, info = optimise(
        sm.points, sm.cells, p, ref_nodes=ref_nodes, wall=wall, wall_normals=sdf.gradient, project=projector, cap_nodes=cap_nodes, cap_normals=cap_normals,
        boundary=boundary, untangle_below=0.0, smooth_below=below, smooth_sweeps=sweeps, smooth_tol=tol, untangle_patience=LIGHT_PASS_PATIENCE,
        ratio_floor=ratio_floor, over_relax=over_relax,
    )
    if p > 1:
        before = scaled_jacobian(sm.points, sm.cells, p, ref_nodes)
        after = scaled_jacobian(X, sm.cells, p, ref_nodes)
        info["order_p"] = {"before": {"min": float(before.min()), "mean": float(before.mean())}, "after": {"min": float(after.min()), "mean": float(after.mean())}}
        if after.min() < before.min() or after.mean() <= before.mean():
            ctx.report.sections[name] = _refused(info, "order-p minimum dropped or mean did not rise")
            return
    elif info.get("before") and info["before"]["min"] <= 0 and info["after"]["min"] < info["before"]["min"]:
        # an inverted input: the pass's own untangling (Newton steps on the functional, not
        # judged by the minimum) can fold the mesh further (seed-1 g0016 extracted: 5
        # inverted at -0.419 in, 7 at -0.467 out); on a valid input every step is monotone
        ctx.report.sections[name] = _refused(info, "minimum dropped on an inverted mesh")
        return
    sm.points[:] = X
    info["kept"] = True
    ctx.report.sections[name] = info
    ctx.count(**{f"{name}_nodes": info["smoothed_nodes"]})


def _refused(info: dict, why: str) -> dict:
    """The report section of a light pass whose result was not kept: the mesh is the one
    before it, so ``after`` is ``before``; the rejected pass's statistics move to
    ``refused_after`` (order p: ``refused_order_p``) and its node counts to
    ``refused_smoothed_nodes`` / ``refused_moved``."""
    info = dict(info)
    info["kept"], info["refused"] = False, why
    if "after" in info:
        info["refused_after"] = info["after"]
        info["after"] = info.get("before")
    for key in ("untangled_nodes", "smoothed_nodes", "moved"):
        if key in info:
            info[f"refused_{key}"] = info.pop(key)
            info[key] = 0
    if "order_p" in info:  # the order-p measures likewise: kept mesh = before
        order_p = info["order_p"]
        info["refused_order_p"] = order_p
        info["order_p"] = {"before": order_p["before"], "after": order_p["before"]}
    return info


def _worst_pass(ctx, sm, projector, sdf, below, sweeps, ratio_floor=-np.inf):
    """Max-min steps for the nodes of the elements the light pass left below ``below``
    (:func:`vmesh.geometry.optimize.worst.lift_worst`; linear, valid meshes only): the light
    pass keeps each node's sum of qualities from dropping and climbs one corner at a time,
    so where an untangler left several poor elements balanced around a node it stops.
    ``ratio_floor``: the light pass's Jacobian-ratio guard (``-inf`` = none). Returns whether a node moved."""
    import time

    from ..geometry.optimize import _node_kinds
    from ..geometry.optimize.worst import lift_worst
    from ..geometry.quality import hex8_scaled_jacobian

    if sm.order != 1:
        return False
    q = hex8_scaled_jacobian(sm.points, sm.cells)
    if q.min() >= below or q.min() <= 0:
        return False
    ctx.tick(0.98, "worst pass")
    t0 = time.perf_counter()
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    kind, normal, height = _node_kinds(sm.cells, len(sm.points), wall, projector, sdf.gradient, cap_nodes, cap_normals, boundary, True)
    moved, sweeps_run = lift_worst(sm.points, sm.cells, below, kind, normal, height, projector, sdf.gradient, sweeps=sweeps, ratio_floor=ratio_floor)
    after = hex8_scaled_jacobian(sm.points, sm.cells)
    ctx.report.sections["worst_pass"] = {
        "before": {"min": float(q.min()), "mean": float(q.mean())}, "after": {"min": float(after.min()), "mean": float(after.mean())},
        "moved": moved, "sweeps": sweeps_run, "seconds": round(time.perf_counter() - t0, 3),
    }
    ctx.count(worst_pass_nodes=moved)
    return moved > 0


def _keep_untangled(ctx, sm, X, info, changed, **counts):
    """Take the optimised node positions; report what moved when anything did."""
    sm.points[:] = X
    if changed:
        ctx.count(**counts)
        ctx.report.sections["untangle"] = info


@register_filter(
    description="Give every element the skeleton tags of its block as labels (label id, clean names, one 0/1 array per tag).",
    parameters=[
        Parameter("untagged", "str", "vessel", "Label name of elements whose block has no tag (other than inlet/outlet tags)."),
    ],
    reads=("mesh", "blocks"),
    writes=("mesh",),  # label arrays on the mesh
    category="meshing",
)
def label_elements(ctx, untagged):
    """``label`` is an integer per element; ``report.json`` and the VTU field data map it to
    names (:func:`vmesh.io.names.label_names`): the block's tags without the inlet/outlet/wall
    tags (those name boundary patches only), joined by ``_`` (``aneurysm_neck``), else
    ``untagged``. ``report.json`` gets ``labels.table``: each label's and boundary's name in
    every export format."""
    from ..io.names import label_names, names_table

    mesh, blocks = ctx.mesh, ctx.blocks
    names = label_names(blocks.block_tags, mesh.boundary_names.values(), untagged)
    unique = sorted(set(names))
    block_label = np.array([unique.index(n) for n in names], np.int64)
    b = mesh.cell_data["block_id"]
    mesh.cell_data["label"] = block_label[b]
    mesh.label_names = dict(enumerate(unique))
    tags = sorted({t for tt in blocks.block_tags for t in tt})
    for t in tags:
        has = np.array([t in tt for tt in blocks.block_tags])
        mesh.cell_data[f"tag_{t}"] = has[b].astype(np.uint8)
    counts = {unique[i]: int(c) for i, c in enumerate(np.bincount(mesh.cell_data["label"], minlength=len(unique)))}
    bnames = mesh.boundary_names
    bcounts = {bnames.get(int(i), f"boundary_{i}"): int(c) for i, c in zip(*np.unique(mesh.boundary_ids, return_counts=True))}
    ctx.report.sections["labels"] = {
        "names": {int(k): v for k, v in mesh.label_names.items()}, "elements": counts, "boundary_faces": bcounts, "table": names_table(mesh),
    }
    ctx.count(labels=len(unique), boundaries=len(bcounts))


@register_filter(
    description="Scaled Jacobian per element, quality statistics, histogram PNG, and distance of the boundary to the input surface.",
    parameters=[
        Parameter("histogram", "str", "quality_histogram.png", "File name of the histogram in the output folder ('' for none)."),
        Parameter("fail_on_invalid", "bool", True, "Fail when some element has a scaled Jacobian <= 0."),
        Parameter("bins", "int", 50, "Histogram bins.", min=5, max=500),
        Parameter(
            "jacobian_ratio_below",
            "float",
            0.2,
            "Count the elements whose Jacobian ratio (min / max det J over the element's nodes: the taper the scaled Jacobian does not see; "
            "0.2 is an edge about 5 times shorter than the one opposite) is below this, per block layer (report.json: quality.jacobian_ratio).",
            min=0.0,
            max=1.0,
        ),
    ],
    reads=("mesh", "surface"),
    optional_reads=("blocks", "skeleton"),
    writes=("quality", "mesh"),  # mesh: its scaled_jacobian and jacobian_ratio cell arrays
    category="quality",
)
def compute_quality(ctx, histogram, fail_on_invalid, bins, jacobian_ratio_below=0.2):
    """For p > 1 an element's scaled Jacobian is the minimum over its nodes. The boundary
    distance is measured at the wall faces' nodes and centres, relative to the local radius."""
    from ..geometry.projection import wall_projector
    from ..geometry.quality import jacobian_quality, jacobian_ratio_summary, quality_summary
    from ..geometry.transfinite import reference_points

    mesh = ctx.mesh
    ref_nodes = reference_points(mesh.order, mesh.node_distribution)
    # and the taper, which the corner measure does not see (gmsh's minSJ does: docs/robustness.md, h20/fold)
    sj, ratio = jacobian_quality(mesh.points, mesh.cells, mesh.order, ref_nodes)
    mesh.cell_data["scaled_jacobian"] = sj
    mesh.cell_data["jacobian_ratio"] = ratio
    summary = quality_summary(sj)
    projector = wall_projector(ctx.surface)  # the whole surface's cached tree
    cuts = ctx.blocks.info.get("contact_cuts") if ctx.blocks is not None else None
    if cuts is not None and ctx.sdf is not None:  # wall nodes on a contact cut are on the domain's boundary
        from ..geometry.contact_cut import with_cuts

        projector = with_cuts(ctx.sdf, projector, cuts)[1]
    dist = boundary_distance(mesh, ctx.surface, ctx.blocks, projector)
    ratios = jacobian_ratio_summary(ratio, mesh.cell_data.get("layer"), jacobian_ratio_below)
    ctx.quality = {"scaled_jacobian": sj, "summary": summary, "boundary_distance": dist, "jacobian_ratio": ratio}
    ctx.report.sections["quality"] = {"scaled_jacobian": summary, "jacobian_ratio": ratios}
    folds = wall_fold_share(sj, mesh.cell_data["block_id"], ctx.blocks.info.get("wall_fold_blocks")) if ctx.blocks is not None and "block_id" in mesh.cell_data else None
    if folds is not None:
        ctx.report.sections["quality"]["wall_fold_blocks"] = folds
    ctx.report.sections["boundary_distance"] = dist
    ctx.count(sj_min=summary["min"], sj_mean=summary["mean"], invalid=summary["n_invalid"])
    if histogram:
        path = ctx.output_path(histogram)
        if path is not None:
            from ..plots import quality_histogram

            quality_histogram(sj, path, title=f"{ctx.surface.name or 'mesh'}: {mesh.n_cells} elements, p = {mesh.order}", bins=bins)
    if summary["n_invalid"]:
        message = _invalid_message(mesh, sj, summary, folds)
        if fail_on_invalid:
            raise MeshingError(f"{message}; compute_quality.fail_on_invalid=false writes the mesh to inspect them")
        # the mesh is written (to inspect it), but never silently: the run's warnings say so
        ctx.warn(f"the mesh is INVALID: {message} (written because compute_quality.fail_on_invalid=false)")


def _invalid_message(mesh, sj: np.ndarray, summary: dict, folds: dict | None) -> str:
    """What :func:`compute_quality` says about the elements with a scaled Jacobian <= 0:
    how many, their skeleton nodes and blocks (the first ten), the share in the blocks the
    builder flagged as folding on the wall."""
    bad = np.flatnonzero(sj <= 0)
    blocks = np.unique(mesh.cell_data["block_id"][bad])[:10] if "block_id" in mesh.cell_data else np.zeros(0, np.int64)
    nodes = np.unique(mesh.cell_data["node_id"][bad])[:10] if "node_id" in mesh.cell_data else []
    where = ""
    if folds is not None and folds["invalid_inside"]:
        where = (f"; {folds['invalid_inside']} of them lie in the {folds['blocks']} boundary-layer block(s) that the block builder found folding "
                 f"when their wall faces are projected onto the wall (report.json: quality.wall_fold_blocks): a fold of the block structure")
    return (f"{summary['n_invalid']} elements have a scaled Jacobian <= 0 (min {summary['min']:.3f}) next to skeleton node(s) {list(map(int, nodes))} "
            f"(blocks {blocks.tolist()}): mesh_transfinite's untangling could not unfold them (report.json: untangle){where}")


def wall_fold_share(sj: np.ndarray, block_id: np.ndarray, fold_blocks) -> dict | None:
    """Where the worst elements are against the blocks the block builder flagged as folding
    when their wall faces are projected (``blocks.info["wall_fold_blocks"]``, its
    ``projected_wall_quality`` <= 0): the flagged blocks, their elements, the minimum scaled
    Jacobian inside and outside them and the invalid elements inside. None when nothing was
    flagged (or the blocks predate the list). When the minimum inside is the mesh's, its
    worst elements come from the block structure, which the optimiser cannot undo
    (docs/optimiser.md, issue 17)."""
    if not fold_blocks:
        return None
    flagged = np.zeros(int(max(int(np.max(block_id)), max(fold_blocks))) + 1, bool)
    flagged[np.asarray(fold_blocks, np.int64)] = True
    inside = flagged[np.asarray(block_id, np.int64)]
    return {"blocks": len(fold_blocks), "elements": int(inside.sum()),
            "min_inside": float(sj[inside].min()) if inside.any() else None,
            "min_elsewhere": float(sj[~inside].min()) if (~inside).any() else None,
            "invalid_inside": int((sj[inside] <= 0).sum())}


def boundary_distance(mesh, surface, blocks, projector) -> dict:
    """Distance from wall nodes and wall-face centres to the surface, absolute and relative to the local radius."""
    wall = mesh.boundary_ids == 0
    faces = mesh.boundary_faces[wall]
    if len(faces) == 0:
        return {"max": 0.0, "mean": 0.0, "max_rel": 0.0, "mean_rel": 0.0, "node_max": 0.0, "node_max_rel_diagonal": 0.0}
    radius = blocks.block_radius[mesh.cell_data["block_id"][mesh.boundary_cells[wall]]] if blocks is not None else np.ones(len(faces))
    centres = mesh.points[faces].mean(axis=1)  # bilinear centre of each element face
    _, d_c, face = projector.project(centres)
    nodes = np.unique(faces)
    d_n = projector.project(mesh.points[nodes])[1]
    rel = d_c / radius
    return {
        "max": float(d_c.max()),
        "mean": float(d_c.mean()),
        "max_rel": float(rel.max()),
        "mean_rel": float(rel.mean()),
        "node_max": float(d_n.max()),
        "node_max_rel_diagonal": float(d_n.max() / surface.diagonal),
        **_on_cuts(mesh, wall, face),
    }


def _on_cuts(mesh, wall, face) -> dict:
    """Wall faces that lie on a contact cut (the projector answers face
    :data:`~vmesh.geometry.projection.ON_CUT` there, :class:`~vmesh.geometry.contact_cut.CutProjector`;
    faces kept on a touched cap answer another index): their count and area, about twice
    the neck's cross-section that the mesh leaves out; nothing without cuts."""
    from ..geometry.projection import ON_CUT

    on = np.asarray(face) == ON_CUT
    if not on.any():
        return {}
    q = mesh.points[mesh.corner_boundary_faces()[wall][on]]
    area = 0.5 * np.linalg.norm(np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]), axis=1).sum()
    return {"contact_cut_faces": int(on.sum()), "contact_cut_area": float(area)}


@register_filter(
    description="Check that the mesh covers the vessel: share of the input wall farther than a tenth of a radius from the mesh, volume ratio, wall-node distances; fail naming a missing branch or cap.",
    parameters=[
        Parameter("distance", "float", DISTANCE, "Input wall farther than this from the mesh boundary counts as uncovered.", unit="× radius", min=0.001, max=10.0),
        Parameter("patch_area", "float", PATCH_AREA, "A connected uncovered patch larger than this many local cross-sections (π r²) ...", unit="× π r²", min=0.0),
        Parameter("depth", "float", DEPTH, "... that reaches farther than this from the mesh is a missing part of the vessel (facet sag stays below it).", unit="× radius", min=0.0),
        Parameter("end_depth", "float", END_DEPTH, "Depth allowed to a patch beyond one of the mesh's end faces (a rounded closed end past the last cross-section).", unit="× radius", min=0.0),
        Parameter("fail_on_missing", "bool", True, "Fail when part of the vessel is missing from the mesh (false: a warning)."),
        Parameter("voxel_tolerance", "bool", True, "On a voxel (staircase) input surface, add half its measured voxel step to distance: the wall is known only to that."),
        Parameter("own_radius", "bool", True, "Judge an uncovered patch by its own radius (half its chord across the surface) where that is smaller than the skeleton's: a side vessel the skeleton never entered; false: the skeleton's radius alone."),
    ],
    reads=("mesh", "surface", "skeleton"),
    optional_reads=("caps", "blocks"),
    category="quality",
)
def check_coverage(ctx, distance, patch_area, depth, end_depth, fail_on_missing, voxel_tolerance=True, own_radius=True):
    """Measured against the repaired, capped surface the chain started from, its caps left
    out (the mesh ends there); the local radius is the skeleton's. The result is the
    report's ``coverage`` section (see :mod:`vmesh.geometry.coverage`)."""
    from ..geometry.coverage import measure_coverage, surface_facts
    from ..geometry.projection import cached_trees, wall_projector

    mesh, skeleton, caps = ctx.mesh, ctx.skeleton, ctx.caps or []
    # the mesher's projector: wall nodes it kept on a touched cap are measured to that cap
    projector = wall_projector(ctx.surface, caps, kept=ctx.blocks.info.get("touched_caps", ()) if ctx.blocks is not None else ())
    summary, missing = measure_coverage(
        ctx.surface.vertices, ctx.surface.faces, [c.faces for c in caps], [c.name for c in caps],
        mesh.points, mesh.boundary_faces, mesh.boundary_ids, mesh.order,
        skeleton.points, skeleton.edges, skeleton.radii,
        distance=distance, patch_area=patch_area, depth=depth, end_depth=end_depth, branches=skeleton.branches(),
        wall_tree=projector.tree, on_wall=mesh.on_wall, tolerance=None if voxel_tolerance else 0.0, wall_projector=projector,
        own_radius=own_radius, surface_tree=cached_trees(ctx.surface).get("tree"),  # the signed distance's, where built
        facts=surface_facts(ctx.surface),  # computed while pymeshlab decimated, where it did (vmesh.preload)
    )
    ctx.report.sections["coverage"] = summary
    ctx.count(uncovered=summary["uncovered_share"], volume_ratio=summary["volume_ratio"], missing=summary["missing_parts"])
    if not missing:
        return
    worst = missing[0]
    more = f" (and {len(missing) - 1} more part(s))" if len(missing) > 1 else ""
    message = f"the mesh leaves out part of the vessel: {worst.message(depth)}{more} (check_coverage.fail_on_missing=false only warns)"
    if fail_on_missing:
        raise MeshingError(message)
    ctx.warn(message)


# duplicates: a writer's declaration, same shape as export_mesh's and write_blocks', not shared logic
@register_filter(
    description="Write the hexahedral mesh (mesh.vtu with every cell array; boundary faces as boundary.vtp).",
    parameters=[
        Parameter("filename", "str", "mesh.vtu", "Mesh file name in the output folder (.vtu, or any meshio format)."),
        Parameter("boundary", "str", "boundary.vtp", "Boundary faces file (wall/inlet/outlet ids), '' for none."),
    ],
    reads=("mesh",),
    category="export",
)
def write_mesh(ctx, filename, boundary):
    from ..io.mesh import write_boundary, write_mesh as write

    path = ctx.output_file(filename)
    if path is None:
        return
    write(path, ctx.mesh)
    if boundary:
        write_boundary(ctx.output_path(boundary), ctx.mesh)
