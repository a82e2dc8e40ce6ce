"""Exodus II writer (netCDF, through ``netCDF4``): HEX8 element blocks, side sets, node sets.

One element block per label (named by the label), one side set and one node set per
boundary (wall, inlet, outlet_k), every numeric cell array as an element variable of a
single time step, and ``elem_num_map`` giving each element's vmesh index + 1 (elements are
stored block by block).
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from .. import __version__
from .atomic import atomic_path
from .export import boundary_groups, boundary_local_faces, cell_labels, safe_names

#: Exodus HEX8 side number of each local face (i = 0, i = p, j = 0, j = p, k = 0, k = p):
#: side 1 = 1-2-6-5 (j = 0), 2 = 2-3-7-6 (i = p), 3 = 3-4-8-7 (j = p), 4 = 1-5-8-4 (i = 0),
#: 5 = 1-4-3-2 (k = 0), 6 = 5-6-7-8 (k = p).
EXODUS_SIDE = np.array([4, 2, 1, 3, 5, 6])

LEN_STRING = 33


def _names(nc, var, dim, names) -> None:
    v = nc.createVariable(var, "S1", (dim, "len_string"))
    arr = np.zeros((len(names), LEN_STRING), "S1")
    for i, n in enumerate(names):
        b = n.encode()[: LEN_STRING - 1]
        arr[i, : len(b)] = np.frombuffer(b, "S1")
    v[:] = arr


def write(path, mesh) -> Path:
    """Write a linear hexahedral ``mesh`` as an Exodus II file (atomically)."""
    import netCDF4

    path = Path(path)
    labels, lnames = cell_labels(mesh)
    bnames = boundary_groups(mesh)
    # elements stored block by block (stable sort keeps vmesh order within a block)
    order = np.argsort(labels, kind="stable")
    position = np.empty(mesh.n_cells, np.int64)
    position[order] = np.arange(mesh.n_cells)
    side = EXODUS_SIDE[boundary_local_faces(mesh)]
    bid = np.asarray(mesh.boundary_ids)
    corner = mesh.corner_cells()
    variables = {k: np.asarray(v, np.float64) for k, v in mesh.cell_data.items() if np.asarray(v).ndim == 1 and np.asarray(v).dtype.kind in "biuf"}
    with atomic_path(path) as tmp:
        with netCDF4.Dataset(tmp, "w", format="NETCDF3_64BIT_OFFSET") as nc:
            nc.title = f"vmesh {__version__} hexahedral mesh, {datetime.datetime.now().isoformat(timespec='seconds')}"
            if mesh.units:
                nc.units = mesh.units  # length unit of the coordinates
            nc.api_version = np.float32(5.1)
            nc.version = np.float32(5.1)
            nc.floating_point_word_size = np.int32(8)
            nc.file_size = np.int32(1)
            nc.maximum_name_length = np.int32(LEN_STRING - 1)
            for name, size in (("len_string", LEN_STRING), ("len_line", 81), ("four", 4), ("num_dim", 3),
                               ("num_nodes", mesh.n_points), ("num_elem", mesh.n_cells),
                               ("num_el_blk", len(lnames)), ("num_side_sets", len(bnames)),
                               ("num_node_sets", len(bnames))):
                nc.createDimension(name, size)
            nc.createDimension("time_step", None)
            nc.createVariable("time_whole", "f8", ("time_step",))[0] = 0.0
            _names(nc, "coor_names", "num_dim", ["X", "Y", "Z"])
            for axis, c in zip("xyz", mesh.points.T):
                nc.createVariable(f"coord{axis}", "f8", ("num_nodes",))[:] = c
            nc.createVariable("elem_num_map", "i4", ("num_elem",))[:] = order + 1
            ids = np.arange(1, len(lnames) + 1, dtype=np.int32)
            nc.createVariable("eb_status", "i4", ("num_el_blk",))[:] = 1
            prop = nc.createVariable("eb_prop1", "i4", ("num_el_blk",))
            prop.setncattr("name", "ID")
            prop[:] = ids
            _names(nc, "eb_names", "num_el_blk", safe_names(lnames.values()))
            for b, lab in enumerate(lnames, start=1):
                sel = order[labels[order] == lab]
                nc.createDimension(f"num_el_in_blk{b}", len(sel))
                nc.createDimension(f"num_nod_per_el{b}", 8)
                nc.createDimension(f"num_att_in_blk{b}", 1)
                con = nc.createVariable(f"connect{b}", "i4", (f"num_el_in_blk{b}", f"num_nod_per_el{b}"))
                con.elem_type = "HEX8"
                con[:] = corner[sel] + 1
            bsafe = safe_names(bnames.values())
            for name in ("ss", "ns"):
                nc.createVariable(f"{name}_status", "i4", (f"num_{'side' if name == 'ss' else 'node'}_sets",))[:] = 1
                prop = nc.createVariable(f"{name}_prop1", "i4", (f"num_{'side' if name == 'ss' else 'node'}_sets",))
                prop.setncattr("name", "ID")
                prop[:] = np.arange(1, len(bnames) + 1)
            _names(nc, "ss_names", "num_side_sets", bsafe)
            _names(nc, "ns_names", "num_node_sets", bsafe)
            for s, b in enumerate(bnames, start=1):
                on = np.flatnonzero(bid == b)
                nc.createDimension(f"num_side_ss{s}", len(on))
                nc.createVariable(f"elem_ss{s}", "i4", (f"num_side_ss{s}",))[:] = position[mesh.boundary_cells[on]] + 1
                nc.createVariable(f"side_ss{s}", "i4", (f"num_side_ss{s}",))[:] = side[on]
                nodes = np.unique(mesh.boundary_faces[on])
                nc.createDimension(f"num_nod_ns{s}", len(nodes))
                nc.createVariable(f"node_ns{s}", "i4", (f"num_nod_ns{s}",))[:] = nodes + 1
            if variables:
                nc.createDimension("num_elem_var", len(variables))
                _names(nc, "name_elem_var", "num_elem_var", list(variables))
                nc.createVariable("elem_var_tab", "i4", ("num_el_blk", "num_elem_var"))[:] = 1
                for v, values in enumerate(variables.values(), start=1):
                    for b, lab in enumerate(lnames, start=1):
                        sel = order[labels[order] == lab]
                        var = nc.createVariable(f"vals_elem_var{v}eb{b}", "f8", ("time_step", f"num_el_in_blk{b}"))
                        var[0, :] = values[sel]
    return path


def read_sets(path) -> dict:
    """Block, side-set and node-set names and sizes of an Exodus file (to check a round trip).

    Returns ``{"blocks": {name: elements}, "side_sets": {name: faces}, "node_sets": {name: nodes}}``.
    """
    import netCDF4

    def names(nc, var):
        return ["".join(c.decode() for c in row if c).strip() for row in np.asarray(nc.variables[var][:])] if var in nc.variables else []

    with netCDF4.Dataset(path) as nc:
        return {
            "blocks": {n: nc.dimensions[f"num_el_in_blk{i}"].size for i, n in enumerate(names(nc, "eb_names"), 1)},
            "side_sets": {n: nc.dimensions[f"num_side_ss{i}"].size for i, n in enumerate(names(nc, "ss_names"), 1)},
            "node_sets": {n: nc.dimensions[f"num_nod_ns{i}"].size for i, n in enumerate(names(nc, "ns_names"), 1)},
        }
