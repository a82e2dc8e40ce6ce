"""The branch graph under cleaning (stage 4 of the skeleton extraction).

Specks are dropped, spurs short relative to the radius of the vessel they sprout
from are pruned, junctions closer than about a radius merge (a 5-furcation becomes
one degree-5 node), tiny cycles made by voxel noise collapse (true cycles are long
compared to the radius) or, when the number of cycles is known, the extra ones are
cut at their narrowest branch (cycles thinner everywhere than any vessel, tunnels
where the wall pinches, are cut whatever the count); junctions are then centred
where their branch axes meet.
"""

from __future__ import annotations

import numpy as np

from .clean import select_spurs
from .probe import SdfFunction, _arclength, evaluate_sdf, maximise_sdf


class BranchGraph:
    """A skeleton under cleaning: nodes with a position and radius, branches with a
    medial polyline (interior points and their radii, ordered from the branch's
    ``start`` node).

    A ``networkx.MultiGraph`` holds the topology (branches may be parallel or
    loops); its size is the number of branches, not of voxels.
    """

    def __init__(self):
        import networkx as nx

        self.graph = nx.MultiGraph()
        self._next_node = 0

    # -- construction --------------------------------------------------------
    def add_node(self, position, radius, **attributes) -> int:
        node = self._next_node
        self._next_node += 1
        self.graph.add_node(node, pos=np.asarray(position, float), r=float(radius), **attributes)
        return node

    def add_branch(self, u: int, v: int, points=None, radii=None) -> int:
        points = np.zeros((0, 3)) if points is None else np.asarray(points, float).reshape(-1, 3)
        radii = np.zeros(0) if radii is None else np.asarray(radii, float).reshape(-1)
        return self.graph.add_edge(u, v, start=u, pts=points, rad=radii)

    # -- queries --------------------------------------------------------------
    def pos(self, node: int) -> np.ndarray:
        return self.graph.nodes[node]["pos"]

    def radius(self, node: int) -> float:
        return self.graph.nodes[node]["r"]

    def degree(self, node: int) -> int:
        return self.graph.degree(node)

    def branches(self):
        """``(u, v, key)`` of every branch."""
        return list(self.graph.edges(keys=True))

    def polyline(self, u: int, v: int, key: int, start: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Points (with both end nodes) and radii of a branch, oriented from ``start``."""
        data = self.graph.edges[u, v, key]
        a = data["start"]
        b = v if a == u else u
        pts = np.concatenate([self.pos(a)[None], data["pts"], self.pos(b)[None]])
        rad = np.concatenate([[self.radius(a)], data["rad"], [self.radius(b)]])
        if start is not None and start != a:
            return pts[::-1].copy(), rad[::-1].copy()
        return pts, rad

    def length(self, u: int, v: int, key: int) -> float:
        """Arclength of a branch, end nodes included."""
        pts, _ = self.polyline(u, v, key)
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    def other(self, u: int, v: int, node: int) -> int:
        return v if node == u else u

    # -- edits ----------------------------------------------------------------
    def contract(self, keep: int, drop: int) -> None:
        """Merge node ``drop`` into ``keep``; its branches are re-attached to ``keep``
        (a branch between the two becomes a loop at ``keep``)."""
        g = self.graph
        for u, v, key, data in list(g.edges(drop, keys=True, data=True)):
            far = self.other(u, v, drop)
            target = keep if far == drop else far
            start = keep if data["start"] == drop else data["start"]
            g.add_edge(keep, target, start=start, pts=data["pts"], rad=data["rad"])
        g.remove_node(drop)

    def dissolve(self, node: int) -> bool:
        """Join the two branches of a degree-2 node (not a loop) into one."""
        g = self.graph
        incident = list(g.edges(node, keys=True))
        if g.degree(node) != 2 or len(incident) != 2:  # a lone loop also has degree 2
            return False
        (a, b, k1), (c, d, k2) = incident
        x, y = self.other(a, b, node), self.other(c, d, node)
        if x == node or y == node:
            return False
        p1, r1 = self.polyline(a, b, k1, start=x)
        p2, r2 = self.polyline(c, d, k2, start=node)
        g.remove_edge(a, b, k1)
        g.remove_edge(c, d, k2)
        g.remove_node(node)
        g.add_edge(x, y, start=x, pts=np.concatenate([p1[1:], p2[1:-1]]), rad=np.concatenate([r1[1:], r2[1:-1]]))
        return True

    def dissolve_all(self) -> None:
        """Join the branches at every degree-2 node (:meth:`dissolve`)."""
        for node in [n for n in self.graph.nodes if self.graph.degree(n) == 2]:
            if node in self.graph:
                self.dissolve(node)

    def split(self, u: int, v: int, key: int, index: int) -> int:
        """Insert a node at interior point ``index`` of a branch; returns the new node."""
        data = self.graph.edges[u, v, key]
        a = data["start"]
        b = self.other(u, v, a)
        pts, rad = data["pts"], data["rad"]
        node = self.add_node(pts[index], rad[index])
        self.graph.remove_edge(u, v, key)
        self.add_branch(a, node, pts[:index], rad[:index])
        self.add_branch(node, b, pts[index + 1 :], rad[index + 1 :])
        return node

    # -- cleaning -------------------------------------------------------------
    def drop_small_components(self, ratio: float) -> int:
        """Remove components whose total branch length is below ``ratio`` x their
        largest radius (specks of the voxel mask); the largest component stays."""
        import networkx as nx

        comps = [list(c) for c in nx.connected_components(self.graph)]
        if len(comps) <= 1:
            return 0
        sizes = []
        for c in comps:
            sub = self.graph.subgraph(c)
            total = sum(self.length(u, v, k) for u, v, k in sub.edges(keys=True))
            rmax = max(self.radius(n) for n in c)
            sizes.append((total, rmax))
        largest = int(np.argmax([s[0] for s in sizes]))
        removed = 0
        for i, (c, (total, rmax)) in enumerate(zip(comps, sizes)):
            if i != largest and total < ratio * rmax:
                self.graph.remove_nodes_from(c)
                removed += 1
        return removed

    def prune_spurs(self, ratio: float, keep=None) -> int:
        """Remove terminal branches that barely stick out of the vessel they leave.

        A terminal branch from junction ``j`` to tip ``t`` is a spur when
        ``max_p (|p - j| + r_p) / r_j < ratio`` over its points ``p`` (:meth:`reach`): no
        inscribed ball along it, the tip's included, hardly leaves the junction's ball
        (surface noise, the rim of a flat end); the candidates are pruned in the order of
        their tip's reach ``(|t - j| + r_t) / r_j``. Up to
        ``1.5 x ratio`` it is also a spur unless it ends in a bulb (its radius
        grows again after a neck, as into an aneurysm sac): a branch whose radius
        only shrinks towards a tip that close leaks into a wide saddle (between
        two branches leaving a wide vessel) or a bulge. A real side branch reaches
        well beyond. The least salient spurs go first; a junction keeps at least
        one branch: both cleanings choose with :func:`~.clean.select_spurs`.

        ``keep``, optional, ``keep([(u, v, key, tip, base), ...]) -> bool array``: the
        candidates that stay whatever their length (the extraction passes the ends at a
        flat end face, :func:`~.ends.spurs_at_flat_ends`).
        """
        removed = 0
        while True:
            candidates = []
            for u, v, k in self.branches():
                du, dv = self.degree(u), self.degree(v)
                if u == v or min(du, dv) != 1 or max(du, dv) < 3:
                    continue
                tip, base = (u, v) if du == 1 else (v, u)
                score = self.reach(u, v, k, base) / max(self.radius(base), 1e-12)
                if score >= 1.5 * ratio or (score >= ratio and self.ends_in_bulb(u, v, k, base)):
                    continue
                # the order of pruning (salience) stays the tip's reach
                tip_reach = float(np.linalg.norm(self.pos(tip) - self.pos(base))) + self.radius(tip)
                candidates.append((tip_reach / max(self.radius(base), 1e-12), u, v, k, tip, base))
            if candidates and keep is not None:
                held = keep([c[1:] for c in candidates])
                candidates = [c for c, h in zip(candidates, held) if not h]
            if not candidates:
                return removed
            degree = {c[5]: self.degree(c[5]) for c in candidates}
            touched = set()
            for i in select_spurs([c[0] for c in candidates], [c[5] for c in candidates], degree):
                _, u, v, k, tip, base = candidates[i]
                self.graph.remove_edge(u, v, k)
                self.graph.remove_node(tip)
                touched.add(base)
                removed += 1
            for node in touched:
                if node in self.graph and self.degree(node) == 2:
                    self.dissolve(node)

    def reach(self, u: int, v: int, key: int, base: int) -> float:
        """How far the inscribed balls along a branch reach from its node ``base``: the
        largest ``|p - base| + r_p`` over its points. For a spur it is the tip's; a branch
        through a side sac reaches farther with the sac's wide ball than with its tip's,
        which ends small in the dome (``tests/test_side_sacs.py``: a generated sac whose
        branch scored 1.92 by its tip)."""
        pts, rad = self.polyline(u, v, key, start=base)
        return float(np.max(np.linalg.norm(pts[1:] - pts[0], axis=1) + rad[1:]))

    def ends_in_bulb(self, u: int, v: int, key: int, base: int, rise: float = 1.15) -> bool:
        """Whether the radius along a branch grows again by ``rise`` after a neck."""
        _, rad = self.polyline(u, v, key, start=base)
        inner = rad[1:]
        if len(inner) < 2:
            return False
        ahead = np.maximum.accumulate(inner[::-1])[::-1]  # largest radius from here to the tip
        return bool(np.max(ahead / np.maximum(inner, 1e-12)) >= rise)

    def axis_line(self, node: int, u: int, v: int, key: int, near: float, far: float):
        """Line (point, unit direction) fitted to a branch between arclengths
        ``near`` and ``far`` from ``node``; ``None`` when the branch is too short."""
        pts, _ = self.polyline(u, v, key, start=node)
        s = _arclength(pts)
        sel = pts[(s >= near) & (s <= far)]
        if len(sel) < 3:
            return None
        centre = sel.mean(axis=0)
        direction = np.linalg.svd(sel - centre, full_matrices=False)[2][0]
        return centre, direction

    def junction_centre(self, node: int, exclude=None) -> np.ndarray:
        """Where the axes of a junction's branches meet (least squares).

        Each branch's axis is fitted beyond the crotch (1.5 to 3.5 junction radii
        away), where the medial axis follows the vessel; the point closest to all
        these lines is the junction centre. The node position is returned when
        fewer than two branches are long enough or the lines meet far away.
        """
        r = self.radius(node)
        x0 = self.pos(node)
        lines = []
        for u, v, k in self.graph.edges(node, keys=True):
            if u == v or (exclude is not None and (u, v, k) in (exclude, (exclude[1], exclude[0], exclude[2]))):
                continue
            line = self.axis_line(node, u, v, k, 1.5 * r, 3.5 * r)
            if line is not None:
                lines.append(line)
        if len(lines) < 2:
            return x0
        a = 1e-3 * len(lines) * np.eye(3)
        b = a @ x0
        for c, d in lines:
            m = np.eye(3) - np.outer(d, d)
            a = a + m
            b = b + m @ c
        x = np.linalg.solve(a, b)
        return x if np.linalg.norm(x - x0) <= 1.5 * r else x0

    def merge_junctions(self, ratio: float) -> int:
        """Merge junctions whose centres are closer than ``ratio`` x the larger radius.

        Thinning splits one furcation into several junctions joined by short
        branches, spread over the crotch; two separate bifurcations a few radii
        apart look alike. The junction centres (where the branch axes meet,
        :meth:`junction_centre`) tell them apart: they coincide for one
        furcation and stay apart for two. The merged node keeps the larger
        inscribed ball.
        """
        merged = 0
        while True:
            best = None
            for u, v, k in self.branches():
                if u == v or self.degree(u) < 3 or self.degree(v) < 3:
                    continue
                rmax = max(self.radius(u), self.radius(v))
                if self.length(u, v, k) > 3.0 * rmax:
                    continue
                gap = float(np.linalg.norm(self.junction_centre(u, (u, v, k)) - self.junction_centre(v, (u, v, k))))
                if gap < ratio * rmax and (best is None or gap / rmax < best[0]):
                    best = (gap / rmax, u, v, k)
            if best is None:
                return merged
            _, u, v, k = best
            keep, drop = (u, v) if self.radius(u) >= self.radius(v) else (v, u)
            self.graph.remove_edge(u, v, k)
            self.contract(keep, drop)
            merged += 1
            self.dissolve_all()

    def center_junctions(self, sdf: SdfFunction, spacing: float, max_shift: float = 0.75, search: float = 0.35) -> int:
        """Place every junction where its branch axes meet, on the ridge of the SDF.

        The start is :meth:`junction_centre` when it is less than ``max_shift``
        junction radii from the node and nearly as deep; from there the SDF is
        maximised within ``search`` junction radii (:func:`maximise_sdf`), which
        puts the node on the vessel axes with sub-voxel accuracy while the axis
        lines fix its place along a vessel that runs straight through. Returns
        the number of junctions.
        """
        nodes = [n for n in self.graph.nodes if self.degree(n) >= 3]
        if not nodes:
            return 0
        old = np.array([self.pos(n) for n in nodes])
        radius = np.array([self.radius(n) for n in nodes])
        centres = np.array([self.junction_centre(n) for n in nodes])
        depth = evaluate_sdf(sdf, centres)
        shift = np.linalg.norm(centres - old, axis=1)
        use = (depth >= 0.8 * radius) & (shift <= max_shift * radius)
        start = np.where(use[:, None], centres, old)
        best, value = maximise_sdf(sdf, start, search * radius, 0.5 * spacing)
        for n, p, d in zip(nodes, best, value):
            self.graph.nodes[n]["pos"] = p
            self.graph.nodes[n]["r"] = float(d)
        return len(nodes)

    def n_cycles(self) -> int:
        """Number of independent cycles (edges - nodes + components)."""
        import networkx as nx

        g = self.graph
        return g.number_of_edges() - g.number_of_nodes() + nx.number_connected_components(g)

    def bottleneck(self, u: int, v: int, key: int) -> float:
        """Smallest radius along a branch (its narrowest passage)."""
        _, rad = self.polyline(u, v, key)
        return float(rad[1:-1].min()) if len(rad) > 2 else float(rad.min())

    def _narrowest_on_cycle(self, g):
        """``(bottleneck, u, v, key)`` of the narrowest branch of ``g`` (this graph's
        branches, or a sub-multigraph of them) that lies on a cycle of ``g``; ``None``
        when ``g`` has no cycle."""
        import networkx as nx

        simple = nx.Graph(g)
        bridges = {frozenset(e) for e in nx.bridges(simple)} if simple.number_of_edges() else set()
        on_cycle = [
            (self.bottleneck(u, v, k), u, v, k)
            for u, v, k in g.edges(keys=True)
            if u == v or g.number_of_edges(u, v) > 1 or frozenset((u, v)) not in bridges
        ]
        return min(on_cycle) if on_cycle else None

    def _cut(self, u: int, v: int, key: int) -> None:
        """Remove a branch (and an end node it leaves alone), then join degree-2 nodes."""
        g = self.graph
        g.remove_edge(u, v, key)
        for node in (u, v):
            if node in g and g.degree(node) == 0:
                g.remove_node(node)
        self.dissolve_all()

    def break_pinched_cycles(self, least_radius: float) -> int:
        """Cut cycles every point of which lies closer than ``least_radius`` to the wall.

        Where the wall pinches (two vessels touching at a point, a ragged rim, noise) the
        surface can have a tunnel a voxel or two wide: a handle that counts in its genus, so
        that :meth:`break_extra_cycles` keeps the loop thinning makes around it. No vessel
        runs there (its lumen is thinner than any vessel the voxels resolve), and the
        junction the loop leaves stands on the wall, pulling the branch it sits on out of
        its vessel. Of the branches whose every radius (end nodes included) is below
        ``least_radius``, those on a cycle of such branches are removed, narrowest first.
        """
        import networkx as nx

        removed = 0
        while True:
            thin = nx.MultiGraph()
            for u, v, k in self.graph.edges(keys=True):
                if self.polyline(u, v, k)[1].max() < least_radius:
                    thin.add_edge(u, v, key=k)
            found = self._narrowest_on_cycle(thin)
            if found is None:
                return removed
            self._cut(*found[1:])
            removed += 1

    def break_extra_cycles(self, keep: int) -> int:
        """Cut cycles until ``keep`` independent ones are left (the genus of the surface).

        Where two vessels run closer than a voxel (the saddle of a narrow crotch,
        two touching vessels) the voxel mask bridges them and thinning turns the
        bridge into a cycle the vessel does not have. Of the branches on cycles,
        the one with the narrowest passage (smallest radius along it) is such a
        bridge and is removed, one at a time.
        """
        removed = 0
        while self.n_cycles() > keep:
            found = self._narrowest_on_cycle(self.graph)
            if found is None:
                break
            self._cut(*found[1:])
            removed += 1
        return removed

    def collapse_small_cycles(self, ratio: float) -> int:
        """Collapse cycles shorter than ``ratio`` x their largest radius into one node.

        Cycles are the fundamental cycles of a minimum spanning tree (by branch
        length): every branch outside the tree closes one; voxel noise makes short
        ones around junctions, a true vascular ring is many radii long.
        """
        import networkx as nx

        collapsed = 0
        while True:
            g = self.graph
            weighted = nx.MultiGraph()
            weighted.add_nodes_from(g.nodes)
            for u, v, k in g.edges(keys=True):
                weighted.add_edge(u, v, key=k, length=self.length(u, v, k))
            tree = nx.minimum_spanning_tree(weighted, weight="length")
            in_tree = {(min(u, v), max(u, v), k) for u, v, k in tree.edges(keys=True)}
            found = None
            for u, v, k, data in weighted.edges(keys=True, data=True):
                if (min(u, v), max(u, v), k) in in_tree:
                    continue
                path = nx.shortest_path(tree, u, v, weight="length")
                cycle_length = data["length"] + nx.path_weight(tree, path, weight="length") if len(path) > 1 else data["length"]
                rmax = max(self.radius(n) for n in path)
                if cycle_length < ratio * rmax and (found is None or cycle_length < found[0]):
                    found = (cycle_length, u, v, k, path)
            if found is None:
                return collapsed
            _, u, v, k, path = found
            g.remove_edge(u, v, k)
            keep = max(path, key=self.radius)
            for node in path:
                if node != keep:
                    self.contract(keep, node)
            # branches left between merged nodes are now loops at ``keep``
            for a, b, key in [(a, b, key) for a, b, key in g.edges(keep, keys=True) if a == b]:
                if self.length(a, b, key) < ratio * self.radius(keep):
                    g.remove_edge(a, b, key)
            collapsed += 1
            self.dissolve_all()

