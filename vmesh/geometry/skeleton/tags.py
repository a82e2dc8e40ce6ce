"""The branch tree from a root, node and edge tags, sac nodes (moved from
:mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...skeleton import Skeleton
from .graph import branch_paths, component_labels, path_edge_ids, _union


@dataclass
class BranchTree:
    """Branches numbered outwards from a root.

    Attributes
    ----------
    paths : list of (k,) int64 arrays
        Branches, each oriented away from the root, numbered in breadth-first order
        (branch 0 starts at the root).
    parent : (b,) int64
        Branch through which each branch was reached; -1 for the first branch of each
        connected component.
    edge_branch : (e,) int64
        Branch of every edge.
    root : int
        Root node of the first component.
    """

    paths: list
    parent: np.ndarray
    edge_branch: np.ndarray
    root: int


def choose_root(skeleton: Skeleton, nodes: np.ndarray | None = None) -> int:
    """The inlet: an endpoint tagged ``inlet`` if there is one, else the endpoint with the
    largest radius, else the node with the largest radius (among ``nodes`` if given)."""
    cand = np.arange(skeleton.n_nodes) if nodes is None else np.asarray(nodes)
    ends = cand[skeleton.degrees[cand] == 1]
    tagged = [i for i in ends.tolist() if "inlet" in skeleton.node_tags[i]]
    if tagged:
        return tagged[0]
    pool = ends if len(ends) else cand
    r = np.nan_to_num(skeleton.radii[pool], nan=-np.inf)
    return int(pool[np.argmax(r)])


def branch_tree(skeleton: Skeleton, root: int | None = None) -> BranchTree:
    """Number the branches breadth-first from ``root`` (default :func:`choose_root`)."""
    n = skeleton.n_nodes
    paths = branch_paths(n, skeleton.edges)
    path_e = path_edge_ids(n, skeleton.edges, paths)
    at = {}
    for k, p in enumerate(paths):
        at.setdefault(int(p[0]), []).append(k)
        if p[-1] != p[0]:
            at.setdefault(int(p[-1]), []).append(k)
    label = component_labels(n, skeleton.edges)
    order, parent, oriented = [], [], []
    done = np.zeros(len(paths), bool)
    first_root = None
    roots = [] if root is None else [int(root)]
    pending = set(np.unique(label[skeleton.edges.ravel()]).tolist()) if skeleton.n_edges else set()
    while pending:
        if roots:
            r = roots.pop()
        else:
            comp = min(pending)
            r = choose_root(skeleton, np.flatnonzero(label == comp))
        pending.discard(int(label[r]))
        if first_root is None:
            first_root = r
        queue = [(r, -1)]
        while queue:
            v, via = queue.pop(0)
            for k in at.get(v, []):
                if done[k]:
                    continue
                done[k] = True
                p = paths[k] if paths[k][0] == v else paths[k][::-1]
                order.append(k)
                parent.append(via)
                oriented.append(p)
                queue.append((int(p[-1]), len(order) - 1))
    edge_branch = np.full(skeleton.n_edges, -1, np.int64)
    new_id = {k: i for i, k in enumerate(order)}
    for k, pe in enumerate(path_e):
        edge_branch[pe] = new_id[k]
    return BranchTree(oriented, np.asarray(parent, np.int64), edge_branch, -1 if first_root is None else first_root)


def tag_nodes(node_tags: list, mask: np.ndarray, tag: str) -> list:
    """A copy of ``node_tags`` with ``tag`` added where ``mask`` is True."""
    out = list(node_tags)
    for i in np.flatnonzero(mask).tolist():
        if tag not in out[i]:
            out[i] = out[i] + (tag,)
    return out


def nodes_in_sphere(points: np.ndarray, center, radius: float) -> np.ndarray:
    """Mask of the points within ``radius`` of ``center``."""
    return np.linalg.norm(np.asarray(points, float) - np.asarray(center, float), axis=1) <= radius


def sac_nodes(skeleton: Skeleton, ratio: float = 1.5, tree: BranchTree | None = None) -> np.ndarray:
    """Mask of nodes whose radius exceeds ``ratio`` x the median radius of the parent
    branch (of their own branch for root branches): an aneurysm sac grows out of a vessel
    much wider than the vessel it sits on. Junctions are never flagged."""
    tree = tree or branch_tree(skeleton)
    r = skeleton.radii
    med = np.array([np.nanmedian(r[p]) if np.isfinite(r[p]).any() else np.nan for p in tree.paths])
    ref = np.where(tree.parent >= 0, med[np.maximum(tree.parent, 0)], med)
    deg = skeleton.degrees
    mask = np.zeros(skeleton.n_nodes, bool)
    for k, p in enumerate(tree.paths):
        inner = p[deg[p] < 3]
        mask[inner] |= r[inner] > ratio * ref[k]
    return mask


def derive_edge_tags(skeleton: Skeleton, rule: str = "both", only_missing: bool = True) -> list:
    """Segment tags from node tags: the tags both end nodes carry (``"both"``) or either
    carries (``"either"``). With ``only_missing`` a segment that has tags keeps them."""
    a, b = skeleton.edges.T
    out = []
    for k, (i, j) in enumerate(zip(a.tolist(), b.tolist())):
        if only_missing and skeleton.edge_tags[k]:
            out.append(skeleton.edge_tags[k])
            continue
        ti, tj = skeleton.node_tags[i], skeleton.node_tags[j]
        out.append(tuple(t for t in ti if t in tj) if rule == "both" else _union(ti, tj))
    return out
