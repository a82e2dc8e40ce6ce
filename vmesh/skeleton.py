"""The skeleton: a centerline graph of nodes (position, radius, tags) and segments."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Skeleton:
    """A centerline graph.

    Attributes
    ----------
    points : (n, 3) float64 array
        Node positions.
    radii : (n,) float64 array
        Vessel radius at each node (maximum inscribed sphere radius).
    edges : (e, 2) int64 array
        Segments between nodes (undirected).
    node_tags : list of tuple of str, length n
        Semantic labels per node (``"aneurysm"``, ``"vessel"``...).
    edge_tags : list of tuple of str, length e
        Semantic labels per segment.
    name : str
        Where the skeleton came from.
    """

    points: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    node_tags: list = field(default_factory=list)
    edge_tags: list = field(default_factory=list)
    name: str = ""

    def __post_init__(self):
        self.points = np.ascontiguousarray(self.points, dtype=np.float64).reshape(-1, 3)
        self.radii = np.ascontiguousarray(self.radii, dtype=np.float64).reshape(-1)
        self.edges = np.ascontiguousarray(self.edges, dtype=np.int64).reshape(-1, 2)
        n, e = len(self.points), len(self.edges)
        if len(self.radii) != n:
            raise ValueError(f"skeleton has {n} nodes but {len(self.radii)} radii")
        if e and (self.edges.min() < 0 or self.edges.max() >= n):
            raise ValueError("skeleton edge refers to a node that does not exist")
        self.node_tags = [tuple(t) for t in self.node_tags] or [()] * n
        self.edge_tags = [tuple(t) for t in self.edge_tags] or [()] * e
        if len(self.node_tags) != n or len(self.edge_tags) != e:
            raise ValueError("skeleton tags do not match its nodes/edges")

    # -- graph structure -------------------------------------------------
    # duplicates: count properties like SurfaceMesh's and HexMesh's: each class counts its own arrays
    @property
    def n_nodes(self) -> int:
        return len(self.points)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @property
    def degrees(self) -> np.ndarray:
        return np.bincount(self.edges.ravel(), minlength=self.n_nodes)

    @property
    def junctions(self) -> np.ndarray:
        """Nodes with three or more neighbours."""
        return np.flatnonzero(self.degrees >= 3)

    @property
    def endpoints(self) -> np.ndarray:
        """Nodes with exactly one neighbour."""
        return np.flatnonzero(self.degrees == 1)

    @property
    def n_components(self) -> int:
        from scipy.sparse.csgraph import connected_components

        return int(connected_components(self.adjacency(), directed=False)[0])

    @property
    def n_cycles(self) -> int:
        """Independent cycles: E - V + components."""
        return int(self.n_edges - self.n_nodes + self.n_components)

    def adjacency(self):
        import scipy.sparse as sp

        n = self.n_nodes
        a, b = self.edges.T
        return sp.coo_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()

    def neighbors(self, i: int) -> np.ndarray:
        adj = self.adjacency()
        return adj.indices[adj.indptr[i] : adj.indptr[i + 1]]

    def edge_lengths(self) -> np.ndarray:
        """Length of every segment ``(e,)``."""
        return np.linalg.norm(self.points[self.edges[:, 1]] - self.points[self.edges[:, 0]], axis=1)

    def branches(self) -> list:
        """Node paths between junctions/endpoints (see :func:`vmesh.geometry.skeleton.graph.branch_paths`)."""
        from .geometry.skeleton.graph import branch_paths

        return branch_paths(self.n_nodes, self.edges)

    def to_networkx(self):
        """A ``networkx.Graph`` with node attributes ``xyz``, ``radius``, ``tags``."""
        import networkx as nx

        g = nx.Graph()
        for i in range(self.n_nodes):
            g.add_node(i, xyz=self.points[i], radius=float(self.radii[i]), tags=self.node_tags[i])
        for k, (a, b) in enumerate(self.edges.tolist()):
            g.add_edge(a, b, tags=self.edge_tags[k])
        return g

    @classmethod
    def from_networkx(cls, g, name: str = "") -> "Skeleton":
        nodes = list(g.nodes)
        index = {v: i for i, v in enumerate(nodes)}
        pts = np.array([g.nodes[v]["xyz"] for v in nodes], float).reshape(-1, 3)
        rad = np.array([g.nodes[v].get("radius", np.nan) for v in nodes], float)
        tags = [tuple(g.nodes[v].get("tags", ())) for v in nodes]
        edges = np.array([(index[a], index[b]) for a, b in g.edges], np.int64).reshape(-1, 2)
        etags = [tuple(g.edges[a, b].get("tags", ())) for a, b in g.edges]
        return cls(pts, rad, edges, tags, etags, name=name)

    def copy(self, **changes) -> "Skeleton":
        kw = dict(
            points=self.points.copy(),
            radii=self.radii.copy(),
            edges=self.edges.copy(),
            node_tags=list(self.node_tags),
            edge_tags=list(self.edge_tags),
            name=self.name,
        )
        kw.update(changes)
        return Skeleton(**kw)

    def tag_names(self) -> list[str]:
        return sorted({t for tags in (*self.node_tags, *self.edge_tags) for t in tags})

    def summary(self) -> dict:
        deg = self.degrees
        return {
            "nodes": self.n_nodes,
            "segments": self.n_edges,
            "junctions": int((deg >= 3).sum()),
            "endpoints": int((deg == 1).sum()),
            "cycles": self.n_cycles,
            "components": self.n_components,
            "max_degree": int(deg.max()) if len(deg) else 0,
        }

    def __repr__(self) -> str:
        s = self.summary()
        return (
            f"Skeleton({self.name!r}: {s['nodes']} nodes, {s['segments']} segments, "
            f"{s['junctions']} junctions, {s['endpoints']} endpoints, {s['cycles']} cycles)"
        )
