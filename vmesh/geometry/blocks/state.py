"""The block builder's mutable state, by concern: the skeleton's branches and junctions
(:class:`_Topology`), its ends (:class:`_Ends`), where sections go along branches
(:class:`_Placement`), the sections' frames (:class:`_Frames`) and the last assembly's
index (:class:`_Assembled`). The builder creates one of each in ``__init__``; its steps
change their fields."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...skeleton import Skeleton


@dataclass
class _Topology:
    """The skeleton being built on, cut into branches between junctions."""

    sk: Skeleton  # split into 3-junctions where its n-furcations are beyond the scheme
    pos: np.ndarray | None = None  # (n, 3) node positions (junction nodes may move)
    paths: tuple | None = None  # (node paths, edge ids) of the branches
    branches: list = field(default_factory=list)  # _Branch per path
    junctions: dict = field(default_factory=dict)  # node -> _Junction
    crowded: set = field(default_factory=set)  # branches between two junctions that ever lacked room
    territory: object = None  # the kept prep.Territory of the section rays' cut (keyed by the skeleton)


@dataclass
class _Ends:
    """Open ends (on caps) and their boundary names."""

    caps: list  # the vessel's flat open ends (vmesh.caps.Cap)
    cap_of: dict = field(default_factory=dict)  # endpoint -> its cap
    end_id: dict = field(default_factory=dict)  # endpoint -> boundary id of its open end
    boundary_names: dict = field(default_factory=dict)  # boundary id -> name
    warned_caps: bool = False  # caps without an endpoint reported once


@dataclass
class _Placement:
    """Where sections may stand along branches."""

    clear: dict = field(default_factory=dict)  # (branch, side) -> arc length where sections are clear of the junction
    retreat: dict = field(default_factory=dict)  # (branch, side) -> how far a closed end's section moves back


@dataclass
class _Frames:
    """Section centres and frames of the current placement (:meth:`section_geometry`)."""

    X: np.ndarray | None = None  # (B, Kmax, 3) section centres per branch
    T: np.ndarray | None = None  # (B, Kmax, 3) section normals
    E1: np.ndarray | None = None  # (B, Kmax, 3) transported reference directions
    counts: np.ndarray | None = None  # (B,) sections per branch
    R_node: list = field(default_factory=list)  # per branch: radius at each section
    max_twist: float = 0.0  # degrees between consecutive sections, after spreading
    domes: list = field(default_factory=list)  # cap-of-blocks corners per closed end (:meth:`_dome_cap`)


@dataclass
class _Assembled:
    """Index of the last assembled block structure."""

    block_where: np.ndarray | None = None  # (nb, 2) branch and segment of each block
    block_layers: np.ndarray | None = None  # (nb,) layer of each block
    corners: np.ndarray | None = None  # (nb, 8) corner Jacobians (BlockStructure.corner_jacobians)
    unflipped: tuple | None = None  # (vertices, hexes, corner Jacobians) before mirrored blocks were flipped
    info: dict = field(default_factory=dict)  # what the builder reports in ``BlockStructure.info``
    wall_faces: dict = field(default_factory=dict)  # the last projected_wall_quality's faces and results
