"""Assemble a conforming hexahedral block structure from a skeleton and a signed distance.

Method (see :mod:`vmesh.geometry.cross_sections` for the kernels)
----------------------------------------------------------------
1. **Junctions.** Every node with three or more neighbours gets a reference line
   ``(c, u)``; its neighbours are ordered around ``u`` and the space around it is split by
   half-planes through the line, one between each pair of consecutive neighbours. Each
   half-plane carries a *half cross-section* (half O-grid) whose outer corners are found by
   casting rays from the junction node within the half-plane; the diameter on the line is
   shared by all of them. Each half-plane may be rotated about ``u``: by default the
   rotation keeping the half-section closest to the junction node on average, among those
   that leave the neighbouring branches room for their first blocks.
2. **Branches.** The skeleton is cut into branches between junctions and endpoints
   (cycles without junctions are branches that close on themselves). Every other node gets
   a full cross-section: the bisecting plane of its two segments, the cap plane at an open
   end (moved back behind a ragged rim's notches, where the cap's cone would cut the
   section's rays short: :meth:`~.sections._Sections._behind_notches`), the plane normal
   to the segment at a closed end (moved back from the endpoint to
   about the dome's centre; the dome beyond it is filled by a half-ball O-grid whose
   boundary layer continues the wall's). Near a junction, sections that would still reach
   into the other branches (rays much longer than the branch radius) or sit behind the
   half-sections' reach are moved along the branch until they are clear.
3. **Frames.** The reference direction of each section is transported along its branch
   by rotation-minimising frames (double reflection) from one end; the twist left at the
   other end (modulo the template's symmetry) is spread evenly by arc length.
4. **Blocks.** Consecutive sections of a branch are joined quad by quad into hexahedra.
   A branch's end section at a junction is the union of its two adjacent half-sections,
   folded along ``u``; neighbouring branches share the half-section vertices, so the
   structure is conforming by construction.
5. **Validity.** Every block must have positive Jacobians at its eight corners. Failing
   blocks are fixed by moving sections further from junctions, re-rotating junction
   half-planes, straightening tilted planes and shrinking the core; a block that stays
   invalid raises :class:`~vmesh.errors.MeshingError` naming its skeleton node.
"""

from __future__ import annotations

import copy

import numpy as np

from ...blocks import BlockStructure
from ...errors import MeshingError
from ...skeleton import Skeleton
from .. import cross_sections as cs
from .assemble import _Assembly
from .centring import centre_regular_nodes
from .crossings import bend_note, without_bends
from .checks import _Failure, fill_quality, filled, wall_left_out
from .crotch import column_ends, split_saddle_columns
from .dents import add_dent_sections
from .junctions import _Junctions
from .options import BlockOptions, _LocalFixes
from .poor import _PoorBlocks
from .prep import MERGE_COVER_DEPTH, merge_junction_pair, pair_wall, split_nonplanar_junctions
from .repair import _Repair
from .reroot import N_PLACEMENTS, reroot_backwards_siblings
from .sections import _Sections
from .stubs import _Stubs, cut_stubs, label_ostia, stub_note
from .state import _Assembled, _Ends, _Frames, _Placement, _Topology
from .work import WorkBudget


def build_blocks(
    skeleton: Skeleton,
    distance,
    caps=None,
    options: BlockOptions | None = None,
    bad_blocks_path=None,
    warn=None,
    progress=None,
    project=None,
    intersect_lines=None,
    work: WorkBudget | None = None,
) -> BlockStructure:
    """Build the block structure of a vessel.

    Parameters
    ----------
    skeleton : Skeleton
        Centerline graph with radii, coarsely resampled (node spacing ~1-2 radii).
    distance : callable
        ``distance(points (n, 3)) -> (n,)`` signed distance, positive inside the vessel.
    caps : list of vmesh.caps.Cap, optional
        Flat open ends. Endpoints near a cap end on its plane with their end faces named
        after it; endpoints without a cap are closed (a cap of blocks fills the dome). Without
        any caps every endpoint is an open end, named by decreasing radius.
    options : BlockOptions
    bad_blocks_path : path, optional
        Where invalid blocks are written (VTU) before failing.
    warn, progress : callable, optional
        ``warn(message)`` and ``progress(fraction, message)``.
    project : callable, optional
        ``project(points) -> closest wall points``: when given, boundary-layer blocks are
        also checked with their wall faces projected onto the wall and thickened where they
        would fold (:func:`projected_wall_quality`).
    intersect_lines : callable, optional
        Line casts on the same surface
        (:meth:`~vmesh.geometry.sdf.SignedDistance.intersect_lines`): the section rays
        then find the wall by one cast each instead of bisecting ``distance``
        (:func:`~vmesh.geometry.cross_sections.cast_rays`).
    work : WorkBudget, optional
        Assemblies spent and rays cast so far (default: a new ``options.repair.work_budget``).

    Returns
    -------
    BlockStructure
        With ``info`` holding ``max_twist_deg``, ``fixes`` and per-junction details.
    """
    options = options or BlockOptions()
    work = work or WorkBudget(options.repair.work_budget)
    blocks = _build_blocks(skeleton, distance, caps, options, bad_blocks_path, warn, progress, project, intersect_lines, work, reroot=True)
    if project is None or options.repair.dent_sections <= 0:
        return blocks

    def fill(b, subset):
        return fill_quality(b, subset, project, distance, intersect_lines)

    plain = options if options.last.bend_drops == 0 else options.replace(bend_drops=0)  # the dent step's builds: without :mod:`.crossings`

    rebuild = _Rebuilds(lambda sk, heard, w: _build_blocks(sk, distance, caps, plain, None, heard.append, None, project, intersect_lines, w),
                        options.repair.work_budget, work.rays)
    dented = add_dent_sections(blocks, rebuild, fill, distance, project, options.repair.dent_sections, warn)
    if dented is not blocks:  # built again on the changed skeleton: what the first build did to the skeleton still holds
        dented.info["fixes"][:0] = dented.info["skeleton_fixes"] = blocks.info.get("skeleton_fixes", [])
        dented.info["cut_stubs"] = label_ostia(dented, blocks.info.get("cut_stubs", []))
    return dented


class _Rebuilds:
    """:func:`~.dents.add_dent_sections`' ``build``: the whole build on another skeleton, each
    with its own work budget, remembered by the skeleton.

    Two rounds of halving often ask for the same skeleton: round 1 tries the flagged set and
    keeps a part, round 2 flags the rest, and halving it on round 1's skeleton gives round
    1's first trial again (s0 g0019 given), or the same up to the new nodes' numbering (s0
    g0007 extracted, g0008 extracted). A build depends on its skeleton (numbering included)
    and options alone, so the same skeleton gets a copy of the first build. The same up to
    numbering gets that build relabelled (segments and nodes mapped by their exact points;
    the block order is the first build's), marked ``info["relabelled"]``: good for judging
    it, and built for real (:meth:`exact`) where the dent step keeps it (and judged again
    where it differs), so the structure kept is the one built (a failed build is
    remembered for its own skeleton only).
    The builds share the first build's :class:`~vmesh.geometry.rays.RayCache` (bit for bit
    the same rays; sections away from the halvings do not move); each ``info["work"]``
    counts its own rays.

    Parameters
    ----------
    build : callable
        ``build(skeleton, heard (list), work) -> BlockStructure``; raises :class:`MeshingError`.
    budget : int
        Each build's work budget (assemblies).
    rays : RayCache
        The cache the builds share.
    """

    def __init__(self, build, budget: int, rays):
        self.build, self.budget, self.rays = build, budget, rays
        self.done: dict = {}  # exact skeleton -> (blocks, warnings) or the MeshingError raised
        self.shapes: dict = {}  # _skeleton_key -> the exact key of a skeleton built

    def __call__(self, sk: Skeleton):
        exact = _exact_key(sk)
        first = self.shapes.get(_skeleton_key(sk)) if exact not in self.done else None
        # a failure is not relabelled: whether a build fails may hang on its numbering
        if first is not None and not isinstance(self.done[first], MeshingError) and (out := _relabelled(self.done[first], sk)) is not None:
            return out
        return self.exact(sk)

    def exact(self, sk: Skeleton):
        """The build on ``sk`` itself (built once)."""
        key = _exact_key(sk)
        if key not in self.done:
            work, heard = WorkBudget(self.budget), []
            work.rays = self.rays
            hits, misses = self.rays.hits, self.rays.misses
            try:
                blocks = self.build(sk, heard, work)
                blocks.info["work"].update(rays_cast=self.rays.misses - misses, rays_reused=self.rays.hits - hits)
                self.done[key] = (blocks, heard)
            except MeshingError as exc:  # kept without its frames (the failed builder's arrays)
                self.done[key] = exc.with_traceback(None)
            self.shapes.setdefault(_skeleton_key(sk), key)
        got = self.done[key]
        if isinstance(got, MeshingError):
            raise got
        return copy.deepcopy(got)


def _exact_key(sk: Skeleton) -> tuple:
    """``sk`` exactly: points, radii, segments, tags."""
    return sk.points.tobytes(), sk.radii.tobytes(), sk.edges.tobytes(), repr(sk.node_tags), repr(sk.edge_tags), sk.name


def _relabelled(got, sk: Skeleton):
    """``(blocks, warnings)`` built on a skeleton that is ``sk`` but for the numbering of its
    nodes and segments, with ``block_node`` and ``block_segment`` in ``sk``'s numbering and
    ``info["skeleton"]`` ``sk``; None where the points, radii or tags differ in any bit or
    the build changed its skeleton (a junction split or merged)."""
    blocks, heard = copy.deepcopy(got)
    old = blocks.info.get("skeleton")
    if old is None or old.n_nodes != sk.n_nodes or old.n_edges != sk.n_edges:
        return None
    a, b = np.lexsort(old.points.T), np.lexsort(sk.points.T)
    node = np.empty(sk.n_nodes, np.int64)
    node[a] = b  # old node id -> sk's
    if not (np.array_equal(old.points[a], sk.points[b]) and np.array_equal(old.radii, sk.radii[node])
            and all(old.node_tags[i] == sk.node_tags[node[i]] for i in range(sk.n_nodes))):
        return None
    pair = {tuple(sorted(e)): k for k, e in enumerate(sk.edges.tolist())}
    seg = np.array([pair.get(tuple(sorted(e)), -1) for e in node[old.edges].tolist()], np.int64)
    if np.any(seg < 0) or any(old.edge_tags[k] != sk.edge_tags[seg[k]] for k in range(sk.n_edges)):
        return None
    blocks.block_segment = np.where(blocks.block_segment >= 0, seg[np.maximum(blocks.block_segment, 0)], blocks.block_segment)
    blocks.block_node = np.where(blocks.block_node >= 0, node[np.maximum(blocks.block_node, 0)], blocks.block_node)
    blocks.info["skeleton"], blocks.info["relabelled"] = sk, True
    return blocks, heard


def _build_blocks(skeleton, distance, caps, options: BlockOptions, bad_blocks_path=None, warn=None, progress=None, project=None,
                  intersect_lines=None, work: WorkBudget | None = None, reroot: bool = False) -> BlockStructure:
    """:func:`build_blocks` without :func:`~.dents.add_dent_sections`; ``reroot``: after
    every other try failed, :func:`_rerooted` (the first build only: a rebuild by
    :func:`~.dents.add_dent_sections` keeps the structure it has where it fails)."""
    work = work or WorkBudget(options.repair.work_budget)
    # Each try either succeeds or fails with what might help: splitting n-furcations
    # (alternative pairings in turn) or merging two junctions too close for their own
    # half-sections. Tries are depth-first and bounded; the first failure is reported.
    # Each skeleton is tried with the half-sections at the junction walls' centres first,
    # then, where its blocks stay invalid, on the skeleton nodes (the wall's centre can crowd
    # junctions whose branches part early); only then is the skeleton changed (:func:`_fallback`).
    at_node = options.replace(junction_centre=0.0)
    flat = {id(options): options.replace(junction_lean=0.0), id(at_node): at_node.replace(junction_lean=0.0)}  # :func:`_fallback`
    queue = [(skeleton, [], options, frozenset(), [], None)]  # + the junction pairs a split made, the stubs cut, the wall to cover
    first = None
    # skeletons tried: [the given one and its changes, those from a merge whose wall is
    # judged]; the judged merge is a variant of the plain merge queued after it, so it and its
    # splits get as many tries as the changed skeletons (all but the given one) and do not
    # use up the tries that merge needs (real sv_rpa given, docs/junctions.md h18/pair)
    tries = [0, 0]
    most = [options.repair.max_retopology_tries, options.repair.max_retopology_tries - 1]
    seen = set()  # merging two junctions and splitting the result again can give a skeleton back
    while queue and not work.spent:
        sk, notes, opts, made, cut, wall = queue.pop(0)
        if opts is options and tries[wall is not None] >= most[wall is not None]:
            continue  # a skeleton counts once; its :func:`_fallback` placements always follow
        key = (_skeleton_key(sk), opts.junction.junction_centre, opts.junction.junction_lean)
        if key in seen:
            continue
        seen.add(key)
        tries[wall is not None] += opts is options
        try:
            blocks = _choose_lean(lambda planar: _Builder(sk, distance, caps, opts, warn, progress, project, intersect_lines, work, planar), work)
        except _Failure as failure:
            if (nxt := _fallback(opts, options, at_node, flat, failure.leaned, work)) is not None:
                queue.insert(0, (sk, notes, nxt, made, cut, wall))
                continue
            first = first or failure
            queue[:0] = [(s, n, options, m, cut + c, w or wall) for s, n, m, c, w in _retopology_options(failure, notes, distance, options, made, project)]
            continue
        except MeshingError:
            if (nxt := _fallback(opts, options, at_node, flat, False, work)) is not None:
                queue.insert(0, (sk, notes, nxt, made, cut, wall))
                continue
            if first is None:
                raise  # the skeleton as given is beyond the scheme: say why
            continue  # a changed skeleton that does not work either
        if wall is not None and (depth := float(wall_left_out(blocks, project, *wall).max())) > MERGE_COVER_DEPTH:
            # valid blocks that leave out the wall a merge took into its junction: the next try
            if "was not taken" not in first.hint:  # said once, however many of its descendants are refused
                first.hint += f"; a merge that left out {depth:.2f} radii of the wall was not taken"
            continue
        notes = notes + _fallback_notes(opts, options)
        for note in notes:
            if warn:
                warn(note)
        blocks.info["fixes"][:0], blocks.info["cut_stubs"] = notes, label_ostia(blocks, cut)
        blocks.info["skeleton_fixes"] = list(notes)  # the retopology's notes (a rebuild by :func:`~.dents.add_dent_sections` keeps them)
        return blocks
    # every try failed: the skeleton as given once more with a last resort (builds that
    # succeed without it stay as they are)
    if (blocks := _last_resort(skeleton, distance, caps, options, (warn, progress, project, intersect_lines), work)) is not None:
        return blocks
    if first is None:
        # nothing but the last resort was tried (a budget spent before the first assembly, or no tries allowed):
        # say so instead of failing on the missing failure
        last = "were not made either" if work.spent else "failed"
        raise MeshingError(f"build_block_structure: no try of the skeleton was made (max_retopology_tries = "
                           f"{options.repair.max_retopology_tries}) and its last tries {last}{work.stop_note()}")
    hooks = (warn, progress, project, intersect_lines)
    if (blocks := _without_bends(first, distance, caps, options, hooks, work)) is not None:
        return blocks
    if reroot and (blocks := _rerooted(first, distance, caps, options, hooks)) is not None:
        return blocks
    first.hint += work.stop_note()
    raise first.error(bad_blocks_path, sum(tries))


def _last_resort(skeleton, distance, caps, options: BlockOptions, hooks: tuple, work) -> BlockStructure | None:
    """:func:`build_blocks` with each of :func:`_last_tries` in turn; the first structure
    built, or None."""
    for last in _last_tries(options):
        if work.spent:
            break
        try:
            blocks = _build_blocks(skeleton, distance, caps, last, None, *hooks, work)
        except MeshingError:
            continue
        if last.last.spread_tight:
            blocks.info["fixes"].insert(0, "last try: junction clearances end at their own crowded stretch, and the cross-sections of "
                                           "branches between two junctions without room spread between the junctions' reaches")
        return blocks
    return None


def _without_bends(first, distance, caps, options: BlockOptions, hooks: tuple, work) -> BlockStructure | None:
    """:func:`_build_blocks` (no dent step) on the skeleton of the first failure without the bend nodes whose
    sections crossed their neighbours (:mod:`.crossings`), after every other try and the last
    tries failed; the structure built, or None.

    All its rounds share one extra work budget (the failed tries have spent theirs; the
    rays are shared too): the first round makes it, the later ones (inside it, one round
    less of drops each) draw on it, so a build spends at most twice ``work_budget``. It is
    not offered inside a last try (its own last tries run inside it)."""
    repair, last = options.repair, options.last
    if last.bend_drops <= 0 or not first.bends or last.straighten_stuck_ends or last.spread_tight:
        return None
    if work.bend_rounds:
        extra = work  # a later round: the first round's extra budget
    else:
        extra = WorkBudget(repair.work_budget)
        extra.rays, extra.bend_rounds = work.rays, True
    if extra.spent:
        return None
    note = bend_note(first.bends)
    try:
        blocks = _build_blocks(without_bends(first.skeleton, first.bends), distance, caps, options.replace(bend_drops=last.bend_drops - 1),
                               None, *hooks, extra)
    except MeshingError:
        first.hint += f"; {note.split(':')[0]} did not help either"
        return None
    return _noted(blocks, note, hooks[0])


#: the work budget's share each ring placement of a re-rooted branch's first node gets
#: (:func:`_rerooted`): a placement that builds has valid blocks within a few assemblies (s1
#: g0012 given: after 5, the rest relieve wall folds; one that fails spends 130-220 of them
#: on fixes), so the 16 placements together cost about two budgets
PLACEMENT_WORK_SHARE = 1 / 8


def _rerooted(first: _Failure, distance, caps, options: BlockOptions, hooks: tuple) -> BlockStructure | None:
    """The last try of all: on the skeleton of the first failure, each crowded junction
    pair's sibling that runs backwards in the link's lumen past its middle re-rooted at the
    link's other end (:func:`.reroot.reroot_backwards_siblings`), built with all the
    builder's tries on a work budget of its own (the tries before spent theirs: s1 g0012
    given spends the whole budget before it gets here). Taken only where its blocks still
    cover the pair's wall, as the own-lumen merge (a re-rooted first segment can cut the
    branch's fused stretch out of the blocks: s1 g0016 given, docs/junctions.md h21/pair).
    Where the re-rooted branch's new first node at the deepest point of its section
    fails, its ring placements (:func:`.reroot.section_placements`) are tried in turn, each
    on the skeleton as re-rooted only and ``PLACEMENT_WORK_SHARE`` of a budget (s1 g0012
    given builds at one of them, docs/junctions.md h25/builder).
    Only runs whose every other try failed reach it, so no structure built today changes.
    Needs the wall projector (``project``) for that judgement; the first structure
    taken, or None."""
    if not options.last.reroot_backwards or hooks[2] is None:
        return None
    sk, project = first.skeleton, hooks[2]
    for a, b in first.crowded:
        rays = None  # the placements' rays, cast once
        for placement in range(N_PLACEMENTS):
            changed = reroot_backwards_siblings(sk, a, b, distance, placement)
            if changed is None:
                if placement == 0:
                    break  # no backwards sibling at this pair
                continue  # a placement outside the wall
            if placement == 0:
                work, opts = WorkBudget(options.repair.work_budget), options
                rays = work.rays
            else:
                # the ring's placements: the skeleton as re-rooted only (its own placements of
                # the half-sections, no merges or splits), each on a share of a budget
                budget = options.repair.work_budget  # 0: no bound, for the ring too
                work = WorkBudget(max(1, int(PLACEMENT_WORK_SHARE * budget)) if budget else 0)
                work.rays, opts = rays, options.replace(max_retopology_tries=1)
            hits, misses = work.rays.hits, work.rays.misses  # the ring shares placement 0's rays
            try:
                blocks = _build_blocks(changed, distance, caps, opts, None, *hooks, work)
            except MeshingError:
                continue
            blocks.info["work"].update(rays_cast=work.rays.misses - misses, rays_reused=work.rays.hits - hits)
            if float(wall_left_out(blocks, project, *pair_wall(sk, a, b, project)).max()) > MERGE_COVER_DEPTH:
                continue
            where = "" if placement == 0 else f" (its new first node at ring placement {placement})"
            return _noted(blocks, f"last try: re-rooted a branch of junction nodes {a} / {b} that runs back in the lumen of the branch "
                                  f"between them at the other junction{where}", hooks[0])
    return None


def _noted(blocks: BlockStructure, note: str, warn) -> BlockStructure:
    """``blocks`` with a last try's skeleton change first in its fixes (said through ``warn``)."""
    if warn:
        warn(note)
    blocks.info["fixes"].insert(0, note)
    blocks.info["skeleton_fixes"] = [note, *blocks.info.get("skeleton_fixes", [])]
    return blocks


def _last_tries(options: BlockOptions) -> list:
    """The options of :func:`build_blocks`' last tries after every other try failed: first
    turning the first sections at junction ends out of other fixes towards their chords;
    then (with its own tries, that straightening included) the last-try placement
    (:mod:`.sections`): a junction's clearance along a branch ends at its own crowded
    stretch (a bulge further on is not the junction's), and the sections of branches
    between two junctions without room stand between the two junctions' reaches. Not by
    default: both move sections of builds that work (g0008 extracted, g0002 extracted)."""
    if options.last.straighten_stuck_ends:
        return []
    out = [options.replace(straighten_stuck_ends=True, max_retopology_tries=1)]
    if not options.last.spread_tight:
        out.append(options.replace(spread_tight=True, clear_own_stretch=True))
    return out


def _choose_lean(make, work) -> BlockStructure:
    """Build with leaning half-sections and, where some n-furcation leans, also with
    half-planes there from the start (with ``choose_lean``); finish both and give such a
    junction half-planes where their finished blocks around it score higher by both of
    :meth:`~.repair._Repair.lean_score`'s measures (least corner scaled Jacobian and fill,
    over its own first-segment blocks and those of the junctions one branch away); else
    the lean stays, finished as without ``choose_lean``.

    ``make(planar)`` is a new :class:`_Builder` whose junctions ``planar`` keep to
    half-planes. Neither the fix loop's work under each choice nor the raw fill before the
    wall-fold steps says which ends better (docs/junctions.md): those steps decide much of
    the final minimum, and a junction's choice changes its close neighbours' blocks too.
    Only trees with a leaning n-furcation pay: one more fix loop and the wall-fold steps
    twice (three times where their junctions choose unalike; where that combination is not
    valid, or the work budget is spent before it is built, the whole-tree variant whose
    worst junctions score higher by both). The extra variants build quietly: the kept one's
    warnings are given once it is chosen."""
    lean = make(frozenset())
    if not lean.opt.junction.choose_lean:
        return lean.run()
    said, warn, tick = [], lean.warn, lean.tick
    lean.warn = lambda msg: (said.append(msg), warn(msg))
    blocks = lean.make_valid()
    nodes = sorted(c for c, j in lean.topo.junctions.items() if lean.leans(j))
    if not nodes or work.spent:
        return lean.finish(blocks)
    variants = {frozenset(): (lean, blocks, work.valid_after, said)}
    failed = []

    def build(planar):
        heard = []
        try:
            b = make(planar)
            b.warn, b.tick = heard.append, (lambda f, m="": None)
            variants[planar] = (b, b.make_valid(), work.valid_after, heard)
        except (_Failure, MeshingError) as exc:
            failed.append(f"half-planes at {sorted(planar)}: {exc}")
            return None
        return b

    flat = build(frozenset(nodes))
    if flat is None or set(flat.topo.junctions) != set(lean.topo.junctions):
        # half-planes cannot be built, or the two trees' junctions do not match up
        return _kept(variants[frozenset()], said, warn, tick, work, nodes, {}, "lean", failed, fixes={})
    done = {p: _finished(variants[p], work, nodes) for p in list(variants)}
    score = {c: (done[frozenset()][2][c], done[frozenset(nodes)][2][c]) for c in nodes}
    pick = frozenset(c for c in nodes if _better(score[c][1], score[c][0]))
    if pick not in variants and not work.spent and build(pick) is not None:
        done[pick] = _finished(variants[pick], work, nodes)
    if pick not in done:
        # not built (budget spent), or the junctions' choices interact: the whole-tree variant whose worst junctions score higher
        worst = [np.min([s[k] for s in score.values()], axis=0) for k in (0, 1)]
        pick = frozenset(nodes) if _better(worst[1], worst[0]) else frozenset()
    choice = ", ".join(f"{c}: {'half-planes' if c in pick else 'lean'}" for c in nodes)
    fixes = {str(c): [variants[frozenset()][0].local.work_at.get(c, 0), flat.local.work_at.get(c, 0)] for c in nodes}
    return _kept(variants[pick], said, warn, tick, work, nodes, score, choice, failed, done[pick], fixes)


def _better(flat, lean) -> bool:
    """Whether half-planes' :meth:`~.repair._Repair.lean_score` ``flat`` beats the lean's:
    higher by both measures (else the lean, as without ``choose_lean``, stays)."""
    return bool(np.all(np.asarray(flat) > np.asarray(lean) + 1e-9))


def _finished(variant, work, nodes) -> tuple:
    """``variant`` (builder, blocks, ``work.valid_after``, warnings heard) finished quietly:
    the finished blocks, the warnings heard, and per junction of ``nodes`` its
    :meth:`~.repair._Repair.lean_score`. The leaning variant finishes as without
    ``choose_lean`` (:meth:`~.repair._Repair.choose_planes` may still turn its junctions to
    half-planes), so the choice is between that result and half-planes from the start."""
    builder, blocks, valid_after, heard = variant
    quiet = list(heard)
    builder.warn, builder.tick = quiet.append, (lambda f, m="": None)
    work.valid_after = valid_after
    out = builder.finish(blocks)
    return out, quiet, {c: builder.lean_score(out, c) for c in nodes}


def _kept(variant, said, warn, tick, work, nodes, score, choice, failed, done=None, fixes=None) -> BlockStructure:
    """The finished structure of ``variant`` (builder, blocks, ``work.valid_after`` when they
    were valid, warnings heard; ``done``: already finished by :func:`_finished`), with
    :func:`_choose_lean`'s choice in its record; the warnings of a quietly built variant are
    given now (those in ``said``, given by the lean build, are not repeated), and the steps
    after go to ``warn`` and ``tick``. ``fixes``: per junction the fix loop's fixes at it
    under each choice, for the record."""
    builder, blocks, valid_after, heard = variant
    if done is not None:
        out, heard, _ = done
    for msg in heard:
        if heard is not said and msg not in said:
            warn(msg)
    builder.warn, builder.tick = warn, tick
    work.valid_after = valid_after  # the kept variant's, not the last one built
    if done is None:
        out = builder.finish(blocks)
    else:
        out.info["work"] = work.summary()
    # per junction, lean then half-planes: [least corner scaled Jacobian, fill score]
    out.info["junction_lean"] = {"nodes": nodes, "score_lean_flat": {str(c): np.round(s, 4).tolist() for c, s in score.items()},
                                 "fixes_lean_flat": fixes, "kept": choice, "failed": failed}
    if score:
        out.info["fixes"].insert(0, f"n-furcation half-sections ({choice}): half-planes where their finished blocks at the junction and "
                                    f"its neighbours score higher by corners and by fill (lean / half-planes: "
                                    f"{', '.join(f'{c}: {np.round(a, 3).tolist()} / {np.round(b, 3).tolist()}' for c, (a, b) in score.items())})")
    return out


def _fallback(opts, options, at_node, flat: dict, leaned: bool, work) -> BlockOptions | None:
    """The placement to try the same skeleton with after ``opts`` failed, or None.

    Where some n-furcation's half-sections leaned (:meth:`_Junctions._leaned`), the same
    placement with half-planes (as before leaning existed): a skeleton whose blocks were
    valid with half-planes stays buildable. Then, from the walls' centres, on the nodes."""
    if work.spent:
        return None
    if leaned and id(opts) in flat:
        return flat[id(opts)]
    if opts in (options, flat[id(options)]) and options.junction.junction_centre > 0:
        return at_node
    return None


def _fallback_notes(opts, options) -> list:
    """What a build that succeeded with a :func:`_fallback` placement gave up."""
    return [note for note, used in (
        ("half cross-sections on the junction nodes: at the junction walls' centres the blocks stayed invalid", opts.junction.junction_centre < options.junction.junction_centre),
        ("half-planes at the n-furcations: with leaning half cross-sections the blocks stayed invalid", opts.junction.junction_lean < options.junction.junction_lean)) if used]


def _skeleton_key(sk: Skeleton) -> bytes:
    """The same skeleton up to node numbering: its segments' end points, rounded (a merged
    and re-split junction lands where it was, to rounding)."""
    scale = max(float(np.ptp(sk.points, axis=0).max()), 1e-300) * 1e-9
    seg = np.round(sk.points[sk.edges] / scale).astype(np.int64)  # (e, 2, 3)
    seg = np.sort(seg.view([("", np.int64)] * 3).reshape(len(seg), 2), axis=1).view(np.int64).reshape(len(seg), -1)
    return np.unique(seg, axis=0).tobytes()


def _retopology_options(failure: "_Failure", notes: list, distance, options: BlockOptions, made=frozenset(), project=None) -> list:
    """Skeletons to try after ``failure``, most promising first: without the side-branch
    stubs too short for a block (:mod:`.stubs`), with two junctions merged (when the branch
    between them has no room for their half-sections), or with the failing n-furcations
    split into 3-junctions, one pairing of branches after another. Each comes with the
    junction pairs its splits made (``made``): those are not merged again, which would only
    give back the n-furcation just split; with the stubs it cut; and with the wall its
    blocks must still cover (:func:`.prep.pair_wall`, for a merge that took a fused branch's
    first nodes into the junction, offered only with ``project``; else None)."""
    out = []
    sk = failure.skeleton
    if failure.stubs:
        # the node numbers change: the pairs a split made are forgotten (a merge may come back)
        out.append((cut_stubs(sk, failure.stubs), notes + [stub_note(s) for s in failure.stubs], frozenset(), failure.stubs, None))
    if options.repair.split_nonplanar:
        for a, b in failure.crowded:
            if (a, b) in made:
                continue
            merged, node = merge_junction_pair(sk, a, b)
            note = f"merged junction nodes {a} and {b} (their half cross-sections left the branch between them no room) into node {node}"
            own, _ = merge_junction_pair(sk, a, b, own_lumen=True) if not notes and project is not None else (merged, node)
            if own.n_nodes < merged.n_nodes:
                # a sibling fused with the link past its middle leaves the merged junction (at
                # the link's middle) through its fused nodes past the middle, tried first; only
                # on the skeleton as given: its failed subtree can spend the budget that a merge
                # of a changed skeleton needs (s0 g0002 extracted); taken only where its blocks
                # still cover the pair's wall (real sv_rpa given; docs/junctions.md h16/pair,
                # h17/pair, h18/pair)
                out.append((own, notes + [note + ", a branch fused with the branch between them leaving from its middle"], frozenset(), [],
                            pair_wall(sk, a, b, project)))
            out.append((merged, notes + [note], frozenset(), [], None))
        if failure.nfurcations:
            degree = int(max(sk.degrees[c] for c in failure.nfurcations))
            for rank in range(degree * (degree - 1) // 2):
                split = split_nonplanar_junctions(sk, failure.nfurcations, distance=distance, rank=rank)
                new = frozenset(tuple(sorted(e)) for e in split.edges[sk.n_edges:].tolist())
                out.append((split, notes + [f"split junction node(s) {failure.nfurcations} into 3-junctions (pairing {rank + 1}) after their blocks stayed invalid"], made | new, [], None))
    return out


# ---------------------------------------------------------------------------
# the builder
# ---------------------------------------------------------------------------
class _Builder(_Junctions, _Sections, _Assembly, _Repair, _PoorBlocks, _Stubs):
    def __init__(self, skeleton: Skeleton, distance, caps, options: BlockOptions, warn, progress, project=None, intersect_lines=None,
                 work=None, planar=frozenset()):
        self.opt = options
        self.sdf = distance
        self.intersect_lines = intersect_lines
        self.project = project
        self.warn = warn or (lambda msg: None)
        self.tick = progress or (lambda f, m="": None)
        self.template = cs.o_grid_template(options.section.blocks_around)
        self.fixes: list[str] = []
        self.local = _LocalFixes(planar=set(planar))  # n-furcations built with half-planes (:func:`_choose_lean`)
        # the state the steps change, by concern (:mod:`.state`)
        self.topo = _Topology(skeleton)
        self.ends = _Ends(list(caps or []))
        self.placed = _Placement()
        self.frames = _Frames()
        self.built = _Assembled()
        self.work = work or WorkBudget(options.repair.work_budget)  # shared by a build's tries


    # -- entry ------------------------------------------------------------------
    def run(self) -> BlockStructure:
        """Build the block structure: :meth:`make_valid`, then :meth:`finish`.

        Returns
        -------
        BlockStructure
            Valid blocks with their record in ``info``.

        Raises
        ------
        _Failure, MeshingError
            Where no valid structure is found.
        """
        return self.finish(self.make_valid())


    def make_valid(self) -> BlockStructure:
        """Steps 1-5 of the method: the first valid block structure (raises
        :class:`_Failure` or :class:`MeshingError` where none is found)."""
        from ..skeleton.graph import branch_paths, path_edge_ids

        self.check_skeleton()
        self.tick(0.05, "junctions")
        self.split_if_needed()
        self.topo.pos = self.topo.sk.points.copy()
        paths = branch_paths(self.topo.sk.n_nodes, self.topo.sk.edges)
        self.topo.paths = (paths, path_edge_ids(self.topo.sk.n_nodes, self.topo.sk.edges, paths))
        self.lay_out(ticks=True)
        self.centre_sections()
        blocks = None
        for round_ in range(self.opt.repair.max_fix_rounds + 1):
            self.tick(0.4 + 0.5 * round_ / (self.opt.repair.max_fix_rounds + 1), "blocks")
            blocks = self.assemble()
            J = self.built.corners  # blocks.corner_jacobians(), kept by the assembly
            bad = np.flatnonzero(J.min(axis=1) <= 0)
            if len(bad) == 0:
                break
            if round_ == self.opt.repair.max_fix_rounds or self.work.spent or not self.fix(bad, J):
                self.fail(blocks, bad)
        self.work.valid_after = self.work.used  # the rest (wall folds) is bounded by the options
        return blocks


    def lay_out(self, ticks: bool = False) -> None:
        """The branches, junctions, ends, junction planes and section places, from the
        node positions (``ticks``: report the progress of the first build)."""
        self.make_branches()
        self.build_junctions()
        self.classify_ends()
        if ticks:
            self.tick(0.15, "junction planes")
        self.choose_rotations()
        if ticks:
            self.tick(0.3, "sections")
        self.place_sections()

    def centre_sections(self) -> None:
        """Regular nodes off their sections' middle moved there (:mod:`.centring`), and
        the layout made again from the moved nodes."""
        moved = centre_regular_nodes(self, self.opt.section.centre_sections)
        if not moved:
            return
        self.fixes.append(f"{len(moved)} regular cross-section(s) centred on their chords' middle (nodes {moved[:8]}{' ...' if len(moved) > 8 else ''})")
        self.lay_out()


    def finish(self, blocks: BlockStructure) -> BlockStructure:
        """The steps that only improve the valid ``blocks`` (wall folds, centres, planes),
        and the build's record."""
        if self.opt.repair.poor_block_sj > 0:  # first: the wall-fold steps below judge the blocks it leaves
            blocks = self._kept_valid(self.lift_poor_blocks, blocks)
        if self.project is not None:
            blocks = self._kept_valid(self.thicken_layers, blocks)
            blocks = self._kept_valid(self.choose_centres, blocks)
            blocks = self._kept_valid(self.choose_planes, blocks)
            if self.opt.repair.relieve_wall_folds:
                blocks = self._kept_valid(self.relieve_wall_folds, blocks)
        columns = blocks.info.pop("_columns", None)
        ratio = self.opt.junction.saddle_split
        if self.project is not None and columns is not None and ratio > 0:  # the crotch's saddle (:mod:`.crotch`)
            def fill(b, rows):  # each split judged by its column's fill (:func:`.crotch.column_fill_score`)
                return filled(b, rows, self.project, self.sdf, self.intersect_lines)

            blocks, notes = split_saddle_columns(blocks, self.template, column_ends(columns, self.template.n_quads), self.sdf, self.cast, ratio, fill)
            self.fixes.extend(notes)
        if self.project is not None:  # of the blocks built (split columns included)
            self.report_wall_folds(blocks)
        blocks.info.update(self.built.info)
        blocks.info["fixes"] = list(self.fixes)
        blocks.info["work"] = self.work.summary()
        if self.topo.territory is not None:  # the section rays' territory cut, kept across assemblies
            blocks.info["work"].update(territory_cut=self.topo.territory.cuts.misses, territory_reused=self.topo.territory.cuts.hits)
        self.tick(1.0, "done")
        return blocks


    def _saved_state(self) -> tuple:
        """A copy of the state a fix or an improving step changes (:meth:`_restore_state`
        puts it back)."""
        # the territory cache is keyed by the skeleton it was made for, so the live one serves
        # the restored state too: not copied (on a large tree it holds a tree of tube samples)
        territory, self.topo.territory = self.topo.territory, None
        try:
            return copy.deepcopy((self.topo, self.local, self.placed, self.frames, self.built, self.fixes))
        finally:
            self.topo.territory = territory

    def _restore_state(self, saved: tuple) -> None:
        """Back to a :meth:`_saved_state`, keeping the live territory cache."""
        saved[0].territory = self.topo.territory
        self.topo, self.local, self.placed, self.frames, self.built, self.fixes = saved

    def _kept_valid(self, step, blocks: BlockStructure) -> BlockStructure:
        """``step(blocks)``, one of the steps that only improve a valid structure (wall folds,
        centres, planes); where one of its trial placements cannot be built (a section
        that finds no wall, :class:`MeshingError`), the state and ``blocks`` as they were.

        Such a trial (a first section moved further along a branch that runs beside
        another vessel, say) is a placement not to take, not a reason to fail a structure
        that is already valid."""
        saved = self._saved_state()
        try:
            return step(blocks)
        except MeshingError as exc:
            self._restore_state(saved)
            self.fixes.append(f"kept the valid blocks as they were: a trial placement of {step.__name__} could not be built ({exc})")
            return blocks


    # -- 1. skeleton -------------------------------------------------------------
    def check_skeleton(self):
        sk = self.topo.sk
        if sk.n_edges == 0:
            raise MeshingError("skeleton has no segments: nothing to build blocks along")
        if np.any(sk.edges[:, 0] == sk.edges[:, 1]):
            k = int(np.flatnonzero(sk.edges[:, 0] == sk.edges[:, 1])[0])
            raise MeshingError(f"skeleton segment {k} joins node {sk.edges[k, 0]} to itself")
        key = np.sort(sk.edges, axis=1)
        if len(np.unique(key, axis=0)) != len(key):
            raise MeshingError("skeleton has duplicate segments between the same two nodes")
        if not np.all(np.isfinite(sk.radii)) or np.any(sk.radii <= 0):
            bad = int(np.flatnonzero(~np.isfinite(sk.radii) | (sk.radii <= 0))[0])
            raise MeshingError(f"skeleton node {bad} has no positive radius (run estimate_radii)")
        length = np.linalg.norm(sk.points[sk.edges[:, 1]] - sk.points[sk.edges[:, 0]], axis=1)
        if np.any(length <= 1e-9 * max(1.0, sk.radii.max())):
            k = int(np.argmin(length))
            raise MeshingError(f"skeleton segment {k} between nodes {sk.edges[k, 0]} and {sk.edges[k, 1]} has zero length")
        deg = sk.degrees
        if np.any(deg >= 3) and not self.template.splittable:
            j = sk.junctions[:3].tolist()
            raise MeshingError(
                f"blocks_around = {self.opt.section.blocks_around} gives a 1 x 1 core without a grid line through its centre, "
                f"so junctions (nodes {j}) cannot be split into half cross-sections: use 6, 8 (default), 10 ... blocks around"
            )
        d = np.asarray(self.sdf(sk.points))
        inner = (deg >= 2) & (d <= 0)
        if inner.any():
            k = int(np.flatnonzero(inner)[0])
            raise MeshingError(
                f"skeleton node {k} lies outside the surface (signed distance {d[k]:.3g}); "
                f"{int(inner.sum())} node(s) outside: add clean_skeleton (outside='pull') and resample_skeleton with the sdf "
                "before build_block_structure, which bring grazing nodes inside and stop on a centerline of another vessel"
            )
        if np.any(deg == 0):
            self.warn(f"{int((deg == 0).sum())} isolated skeleton node(s) ignored")
        if sk.n_components > 1:
            self.warn(f"skeleton has {sk.n_components} components: the block structure will too")
