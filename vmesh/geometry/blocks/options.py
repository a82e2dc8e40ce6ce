"""Options of the block builder and its per-junction and per-branch state."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

JUNCTION, OPEN, CLOSED, CYCLE = "junction", "open", "closed", "cycle"


# duplicates: field lists like repair.RepairReport's: declarations, no shared logic
@dataclass
class SectionOptions:
    """Cross-sections: the O-grid template and the planes of ordinary sections."""

    blocks_around: int = 8
    core_size: float = 0.3
    layer_thickness: float = 0.3
    plane_bias: float = 1.0
    own_territory: bool = True  # cut section rays where they cross into a touching vessel
    centre_sections: float = 0.0  # regular nodes more than this share of their rays' mean reach off their chords' middle move there (:mod:`.centring`; 0: never)


@dataclass
class JunctionOptions:
    """Junction placement: axes, half-plane rotations and the branches' first sections."""

    junction_rotation: str = "closest"  # or "bisector"
    rotation_range: float = 0.6
    rotation_candidates: int = 9
    max_out_of_plane: float = 60.0  # degrees
    min_branch_gap: float = 12.0  # degrees
    clear_ray_factor: float = 1.8
    junction_margin: float = 0.3  # × branch radius, between half-sections and the first section
    junction_lean: float = 1.0  # how far n-furcations' half-sections may lean towards the bisector of branches leaving the plane unalike (0: planar)
    choose_lean: bool = False  # build leaning n-furcations with half-planes too, keep per junction the one whose finished blocks there and at its neighbours have the higher least corner SJ (:func:`~.builder._choose_lean`)
    junction_centre: float = 1.0  # how far half-sections' common line moves from the node to the wall's centre (0: at the node)
    saddle_split: float = 0.0  # split a junction end's first block column where its straight wall faces dip this many layers outside the wall (:mod:`.crotch`; 0: never)


@dataclass
class EndOptions:
    """Ends: open ends on caps, closed ends (domes)."""

    cap_distance: float = 1.0  # × radius
    dome_depth: float = 1.0  # wall distance ahead of a closed end's section, × its mean wall distance
    dome_max_retreat: float = 1.5  # × endpoint radius
    dome_keep: float = 0.0  # × branch radius a yielding dome's section stays off the endpoint (0: none)
    touched_caps: tuple = ()  # ids of the caps of open ends in a contact: the section rays' territory ends at their planes, as the contact cut does (:mod:`.ended`)
    short_end_rays: float = 0.0  # an open end's section whose rays reach less than this share of the previous section's moves half way back (0: never; the filter's default is 0.5; docs/optimiser.md, h23/minima, h24/minima)


@dataclass
class RepairOptions:
    """Repairs: invalid blocks, changed skeletons and wall-fold relief."""

    split_nonplanar: bool = True
    max_retopology_tries: int = 8  # whole rebuilds with merged or split junctions
    max_fix_rounds: int = 16
    wall_quality: float = 0.05  # least scaled Jacobian of boundary-layer blocks with projected wall faces
    good_wall_quality: float = 0.3  # projected quality at which a junction end's margin stops growing
    wall_margins: tuple = (0.0, 0.5, 1.0, 2.0)  # extra margins tried at folding junction ends (× radius)
    relieve_wall_folds: bool = True  # re-place junction sections where boundary-layer blocks would fold (fill-judged)
    stub_within_reach: bool = False  # a side branch is a stub only when it ends within REACH_RADII of its own radii past its junction's radius (:mod:`.stubs`; off: wherever it ends within its junction's half-sections)
    poor_block_sj: float = 0.0  # valid blocks whose least corner scaled Jacobian is below this get the invalid-block repairs, kept where they help (:mod:`.poor`; 0: never)
    poor_block_optimised: bool = False  # judge poor_block_sj's rounds by the optimised fill of the blocks they move (:func:`.poor.optimised_summary`: least up, mean not down) instead of the corners
    dent_sections: int = 2  # rounds of cross-sections added halfway along segments whose layer blocks fold on the wall (:mod:`.dents`; 0: none)
    carry_next_nodes: bool = False  # a junction moved apart from a close neighbour takes along the next node of another branch it would bring within its half-sections (:meth:`~.junctions._Junctions._carry_next_nodes`; opt-in)
    work_budget: int = 160  # assemblies of the whole structure one build may do over its fixes and tries (0: unbounded)


@dataclass
class LastTryOptions:
    """The builder's last tries, made only where every other try failed (so a structure
    built without them is the same): on by ``build_blocks`` itself in turn, or opt-in."""

    straighten_stuck_ends: bool = False  # straighten first sections at junction ends out of fixes (build_blocks' last try)
    clear_own_stretch: bool = False  # a junction's clearance along a branch ends at its own crowded stretch (build_blocks' last try)
    spread_tight: bool = False  # sections of a branch between two junctions without room between their reaches (build_blocks' last try)
    reroot_backwards: bool = False  # last try of all: a crowded junction's thin sibling running back in the link's lumen past its middle re-rooted at the other junction (:mod:`.reroot`)
    bend_drops: int = 0  # rounds of dropping bend nodes whose sections cross (:mod:`.crossings`), only where every other try failed (0: none; opt-in)


_GROUPS = {"section": SectionOptions, "junction": JunctionOptions, "ends": EndOptions, "repair": RepairOptions, "last": LastTryOptions}


@dataclass(init=False)
class BlockOptions:
    """Parameters of :func:`build_blocks` (see the filter ``build_block_structure``), in
    groups by concern: :attr:`section`, :attr:`junction`, :attr:`ends`, :attr:`repair` and
    :attr:`last` (the last tries).

    The defaults here are the kernel's: where the filter's default differs (``saddle_split``
    0.5, ``short_end_rays`` 0.5 there, 0 here), a direct caller passes the filter's value to
    get the default chain's structure.

    Built from groups (``BlockOptions(junction=JunctionOptions(junction_centre=0))``) or
    from the filter's flat parameter names (``BlockOptions(junction_centre=0)``), which
    go to the group holding a field of that name; :meth:`replace` takes flat names too.
    """

    section: SectionOptions
    junction: JunctionOptions
    ends: EndOptions
    repair: RepairOptions
    last: LastTryOptions

    def __init__(self, section=None, junction=None, ends=None, repair=None, last=None, **flat):
        given = {"section": section, "junction": junction, "ends": ends, "repair": repair, "last": last}
        groups = {name: replace(given[name]) if given[name] is not None else cls() for name, cls in _GROUPS.items()}
        for key, value in flat.items():
            owner = next((name for name, cls in _GROUPS.items() if key in _FIELDS[cls]), None)
            if owner is None:
                raise TypeError(f"BlockOptions got an unexpected keyword argument {key!r}")
            setattr(groups[owner], key, value)
        self.section, self.junction, self.ends, self.repair, self.last = (groups[name] for name in _GROUPS)

    def replace(self, **flat) -> "BlockOptions":
        """A copy with the given fields (flat names) changed."""
        return BlockOptions(self.section, self.junction, self.ends, self.repair, self.last, **flat)


_FIELDS = {cls: {f.name for f in fields(cls)} for cls in _GROUPS.values()}


@dataclass
class _Candidates:
    """Candidate rotations of a junction's half-planes and the chosen one per separator."""

    psi: np.ndarray  # (m, ncand) rotation of each separator's candidates
    cost: np.ndarray  # (m, ncand) cost of each (inf: no wall found)
    reach: np.ndarray  # (m, ncand, m) how far each reaches along each ordered neighbour
    pick: np.ndarray  # (m,) chosen candidate per separator


@dataclass
class _Junction:
    node: int
    center: np.ndarray
    radius: float
    u: np.ndarray
    p: np.ndarray  # basis of the plane ⟂ u
    q: np.ndarray
    neighbors: np.ndarray  # ordered around u
    dirs: np.ndarray  # (m, 3) directions to the ordered neighbours
    separator: np.ndarray  # (m,) base angles (bisectors), separator h between neighbors h and h+1
    gap: np.ndarray  # (m,)
    psi: np.ndarray  # (m,) chosen rotation of each separator
    ends: list = field(default_factory=list)  # (branch, side) per ordered neighbour
    cand: _Candidates | None = None  # the half-planes' candidate rotations (:meth:`choose_rotations`)
    spine_ids: np.ndarray | None = None  # (nv,) global ids of spine vertices (-1 elsewhere)
    half_ids: np.ndarray | None = None  # (m, nv) global ids of upper-half vertices per separator

    def separator_dir(self, h, psi=None) -> np.ndarray:
        ang = self.separator[h] + (self.psi[h] if psi is None else psi)
        return np.cos(ang)[..., None] * self.p + np.sin(ang)[..., None] * self.q


@dataclass
class _Branch:
    nodes: np.ndarray  # (K+1,)
    edges: np.ndarray  # (K,)
    kinds: list  # [start kind, end kind]
    caps: list  # cap id per end (0 none)
    arc: np.ndarray  # (K+1,) arc length at nodes
    s: np.ndarray  # (K+1,) section positions (arc length)
    margin: np.ndarray = field(default_factory=lambda: np.zeros(2))  # extra clearance per end (× radius)
    straighten: np.ndarray | None = None  # (K+1,) blend of section normals towards the chord


@dataclass
class _LocalFixes:
    """Local changes the builder's fixes make, kept across rebuilds."""

    core_scale: dict = field(default_factory=dict)  # section key -> core size factor
    layer_scale: dict = field(default_factory=dict)  # section key -> boundary-layer thickness factor
    lookahead: dict = field(default_factory=dict)  # junction node -> radii along its branches for their directions
    at_node: set = field(default_factory=set)  # junctions whose half-sections meet on their node, not the wall's centre
    planar: set = field(default_factory=set)  # n-furcations whose half-sections keep to half-planes (:meth:`_Junctions._leaned`)
    work_at: dict = field(default_factory=dict)  # junction node -> fixes the fix loop made at its ends (:func:`~.builder._choose_lean`)
