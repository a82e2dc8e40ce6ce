"""Side-branch stubs too short for a junction's half-sections: found after the blocks stay
invalid, and cut back into their parent (a changed skeleton :func:`build_blocks` tries).

A side branch cut open one or two of its radii past its parent's wall (a *stub*) is shorter
than its junction's half cross-sections reach along it: the half-sections' rays leave through
the stub's cap, so the blocks between the folded end section and the cap section have no
thickness, and a one-segment branch has no section to move. No placement of the half-sections
gives it a block. Such a stub is dropped from the skeleton: its parent is meshed as if the
stub were not there, the stub's cap is left unmeshed with a warning, and the cut is recorded
(``BlockStructure.info["cut_stubs"]``) so that the coverage check names the part left out
instead of passing it silently.
"""

from __future__ import annotations

import numpy as np

from .options import JUNCTION, OPEN
from .sections import REACH_RADII


class _Stubs:
    """Stub detection of the block builder. Mixed into
    :class:`~vmesh.geometry.blocks.builder._Builder`, whose state it shares."""

    def short_stubs(self, bad: np.ndarray) -> list:
        """Open side branches next to the invalid blocks ``bad`` that cannot hold a block.

        A branch counts when it runs from a junction that the invalid blocks touch (or
        holds invalid blocks itself) to an open end (a cap), is the narrowest branch of
        that junction (a side branch, not the vessel's continuation), and ends before the
        junction's half-sections plus the margin the builder keeps (``junction_margin``)
        along it: its cap section cannot stand clear of the junction. With the opt-in
        ``stub_within_reach`` it must also end within ``REACH_RADII`` of its own radii past
        the junction's radius (:meth:`stub_of`).

        Returns
        -------
        list of dict
            Per stub: ``junction`` and ``end`` node, the ``cap`` name, ``length`` and
            ``reach`` along the branch, ``radius``, and the ``start`` and ``end_point``
            positions of the branch (the part that will not be meshed).
        """
        touched = {int(n) for bi in np.unique(self.built.block_where[bad, 0]).tolist()
                   for n in (self.topo.branches[bi].nodes[0], self.topo.branches[bi].nodes[-1])}
        out = []
        for bi, br in enumerate(self.topo.branches):
            if int(br.nodes[0]) in touched and (stub := self.stub_of(bi)) is not None:
                out.append(stub)
        return out

    def stub_of(self, bi: int) -> dict | None:
        """Branch ``bi`` as a stub (see :meth:`short_stubs`), or None when it is no stub: it
        does not run from a junction to an open end, is not its junction's narrowest branch,
        or has room for a section past the junction's half-sections; with the opt-in
        ``stub_within_reach``, also when it runs farther past the junction's radius than a
        half-section bounded by its own wall could reach (``REACH_RADII`` of its radii)."""
        sk, opt = self.topo.sk, self.opt
        br = self.topo.branches[bi]
        if br.kinds != [JUNCTION, OPEN]:
            return None
        j, _, _ = self._junction_end(bi, 0)
        rb = float(np.median(sk.radii[br.nodes]))
        widths = [float(np.median(sk.radii[self.topo.branches[b].nodes])) for b, _ in j.ends]
        if rb > min(widths):
            return None  # not the junction's side branch
        reach = self._junction_reach(bi, 0)
        if br.arc[-1] > reach + opt.junction.junction_margin * rb:
            return None  # room for a section between the half-sections and the cap
        own = float(np.median(sk.radii[br.nodes[1:]]))  # its own radius, the junction's node left out
        if opt.repair.stub_within_reach and br.arc[-1] > j.radius + REACH_RADII * own:
            # longer than any half-section bounded by its own wall reaches along it: the reach
            # runs along a fused neighbour (a merged fan's 9.9 along daughters 8 long), the
            # junction is what fails, and the branch is no stub (docs/junctions.md, h23/fans)
            return None
        end = int(br.nodes[-1])
        cap = self.ends.cap_of.get(end)
        return {
            "junction": int(br.nodes[0]), "end": end, "cap": getattr(cap, "name", f"end node {end}"),
            "length": float(br.arc[-1]), "reach": float(reach), "radius": rb, "junction_radius": float(j.radius),
            "start": sk.points[br.nodes[0]].tolist(), "end_point": sk.points[end].tolist(),
            "nodes": [int(n) for n in br.nodes[1:]],
        }


def cut_stubs(skeleton, stubs: list):
    """The skeleton without the stubs' nodes past their junctions (their junctions stay as
    ordinary nodes of the parent)."""
    from ..skeleton.graph import remove_nodes

    drop = np.zeros(skeleton.n_nodes, bool)
    for s in stubs:
        drop[s["nodes"]] = True
    return remove_nodes(skeleton, drop, bridge=False)


def stub_wall(vertices: np.ndarray, faces: np.ndarray, stubs: list) -> list:
    """Surface area (wall and cap) of each cut stub past its parent's wall, and its share of
    the whole surface.

    A triangle belongs to a stub when its centroid lies along the stub's axis beyond the
    junction's radius (past the parent's wall) and up to its cap, within 1.5 stub radii of
    the axis. That wall is not meshed: the report names it, so that a cut stub never passes
    unaccounted.

    Returns
    -------
    list of dict
        Each stub with ``wall_area`` and ``wall_share`` added.
    """
    V, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
    T = V[F]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    C = T.mean(axis=1)
    out = []
    for s in stubs:
        a0, a1 = np.asarray(s["start"]), np.asarray(s["end_point"])
        ax = (a1 - a0) / max(np.linalg.norm(a1 - a0), 1e-300)
        t = (C - a0) @ ax
        lateral = np.linalg.norm(C - a0 - t[:, None] * ax, axis=1)
        inside = (t > s["junction_radius"]) & (t <= s["length"] + 0.1 * s["radius"]) & (lateral < 1.5 * s["radius"])
        wall = float(area[inside].sum())
        out.append({**s, "wall_area": wall, "wall_share": wall / max(float(area.sum()), 1e-300)})
    return out


def stub_note(stub: dict) -> str:
    """The warning for one cut stub."""
    return (f"cut the side branch at junction node {stub['junction']} back into its parent: it ends at cap "
            f"'{stub['cap']}' {stub['length']:.3g} from the junction, within the junction's half cross-sections "
            f"(they reach {stub['reach']:.3g} along it), so it cannot hold a block; that stub and its cap are not meshed")


def label_ostia(blocks, stubs: list) -> list:
    """Name the wall faces over each cut stub's ostium as a cap of their own (in place);
    returns ``stubs``.

    The parent of a cut stub is meshed as if the stub were not there, so its wall faces
    span the stub's mouth: labelled ``wall``, the mesh would state a wall where a branch
    leaves. A wall face whose centre lies along the stub's axis past half the junction's
    radius and within the stub's radius of the axis gets a new boundary id named
    ``stub_k`` (``k`` counting the cut stubs, ``stub["boundary"]`` records it), so that
    the missing branch shows as an open end of its own, never as wall.
    """
    from ...blocks import FACE_WALL, HEX_FACES

    if not stubs:
        return stubs
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    centre = blocks.vertices[blocks.hexes[b[:, None], HEX_FACES[f]]].mean(axis=1)
    for k, s in enumerate(stubs, 1):
        a0, a1 = np.asarray(s["start"], float), np.asarray(s["end_point"], float)
        ax = (a1 - a0) / max(np.linalg.norm(a1 - a0), 1e-300)
        t = (centre - a0) @ ax
        lateral = np.linalg.norm(centre - a0 - t[:, None] * ax, axis=1)
        mouth = (t > 0.5 * s["junction_radius"]) & (lateral < s["radius"]) & (blocks.face_boundary[b, f] == FACE_WALL)
        if not mouth.any():
            continue
        fid = max(blocks.boundary_names) + 1
        blocks.face_boundary[b[mouth], f[mouth]] = fid
        blocks.boundary_names[fid] = f"stub_{k}"
        s["boundary"] = f"stub_{k}"
    return stubs


def stub_face_ids(blocks) -> np.ndarray:
    """The boundary ids :func:`label_ostia` named ``stub_k`` (cut stubs' mouths)."""
    return np.array([k for k, v in blocks.boundary_names.items() if str(v).startswith("stub_")], np.int64)


def meshed_as_wall(blocks):
    """``blocks`` with the faces over its cut stubs' mouths given back to the wall for meshing
    (a shallow copy; ``blocks`` itself where it cut none).

    The mouth's faces continue the parent's wall where the stub was cut. Meshed as a cap of
    their own they would be neither projected nor free to slide on the wall: the optimisers
    keep cap nodes to one plane, fitted here to a curved patch, and the parent's layer next
    to it folds (seed 0 g0007 extracted: 19 inverted elements against 0 with the mouth meshed
    as wall). Only the name differs: :func:`name_stub_faces` gives it back to the mesh.
    """
    import copy

    from ...blocks import FACE_WALL

    ids = stub_face_ids(blocks)
    if not len(ids):
        return blocks
    out = copy.copy(blocks)
    out.face_boundary = np.where(np.isin(blocks.face_boundary, ids), FACE_WALL, blocks.face_boundary)
    return out


def name_stub_faces(blocks, boundary_ids, boundary_cells, cell_block, local_face) -> np.ndarray:
    """The mesh's boundary ids with the faces over each cut stub's mouth named as ``blocks``
    names them (the mesh made from :func:`meshed_as_wall`'s copy calls them wall).

    A mesh wall face takes the id of the block face it lies on: its element's block
    (``cell_block`` of ``boundary_cells``) and that block's face ``local_face``
    (:func:`~vmesh.geometry.transfinite_lattice.connectivity` records it).
    """
    from ...blocks import FACE_WALL

    ids = stub_face_ids(blocks)
    out = np.array(boundary_ids, copy=True)
    if not len(ids):
        return out
    b = np.asarray(cell_block)[np.asarray(boundary_cells)]
    named = blocks.face_boundary[b, np.asarray(local_face, np.int64)]
    sel = (out == FACE_WALL) & np.isin(named, ids)
    out[sel] = named[sel]
    return out

