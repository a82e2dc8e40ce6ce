"""Thinning a voxel mask to a one-voxel-wide curve skeleton (stage 2).

Distance-ordered homotopic thinning: voxels are peeled in order of increasing
distance to the wall and only simple points (Bertrand & Malandain 1994) are
removed, so tubes become curves along the ridge of the distance and a ring keeps
its cycle. skimage's Lee thinning is not used: it deletes whole straight branches
whose section thins to two voxels (scikit-image issue #3757), which happens for
vessels aligned with the grid.
"""

from __future__ import annotations

import itertools

import numpy as np

from .probe import _OFFSETS26, SdfFunction, evaluate_sdf
from .voxelize import VoxelGrid, fill_cavities


def _neighbourhood_tables():
    """Bit tables of the 3x3x3 neighbourhood (26 positions, the centre excluded).

    Returns the 26-adjacency and the 6-adjacency (within the 18-neighbourhood) of
    every position of :data:`~.probe._OFFSETS26` as bit masks, and the masks of the
    18-neighbourhood and of the 6 face neighbours.
    """
    offsets = _OFFSETS26
    bits = np.left_shift(np.uint32(1), np.arange(26, dtype=np.uint32))
    diff = offsets[:, None, :] - offsets[None, :, :]
    cheb = np.abs(diff).max(axis=2)
    manh = np.abs(diff).sum(axis=2)
    l1 = np.abs(offsets).sum(axis=1)
    in18 = l1 <= 2
    adj26 = np.array([np.bitwise_or.reduce(bits[(cheb[p] == 1)]) for p in range(26)], dtype=np.uint32)
    adj6 = np.array(
        [np.bitwise_or.reduce(bits[(manh[p] == 1) & in18]) if in18[p] else 0 for p in range(26)], dtype=np.uint32
    )
    n18 = np.bitwise_or.reduce(bits[in18])
    faces = np.bitwise_or.reduce(bits[l1 == 1])
    return adj26, adj6, np.uint32(n18), np.uint32(faces)


_ADJ26, _ADJ6, _N18, _FACES = _neighbourhood_tables()


def _flood(seed: np.ndarray, allowed: np.ndarray, adjacency: np.ndarray) -> np.ndarray:
    """Bits reachable from ``seed`` within ``allowed`` (vectorised over configurations)."""
    reached = seed & allowed
    for _ in range(26):
        grown = reached.copy()
        for p in range(26):
            grown |= ((reached >> np.uint32(p)) & np.uint32(1)) * adjacency[p]
        grown &= allowed
        if np.array_equal(grown, reached):
            break
        reached = grown
    return reached



def _lowest_bit(x: np.ndarray) -> np.ndarray:
    return x & (~x + np.uint32(1))



def simple_points(codes: np.ndarray) -> np.ndarray:
    """Whether the centre of each 26-neighbourhood configuration is a simple point.

    ``codes`` holds one bit per neighbour (the order of :data:`_OFFSETS26`). A
    point is simple (removable without changing the topology) when its
    foreground neighbours form exactly one 26-component and the background in its
    18-neighbourhood has exactly one 6-component 6-adjacent to it
    (Bertrand & Malandain 1994).
    """
    codes = np.asarray(codes, dtype=np.uint32)
    one_object = (codes != 0) & (_flood(_lowest_bit(codes), codes, _ADJ26) == codes)
    background = ~codes & _N18
    face_background = background & _FACES
    reached = _flood(_lowest_bit(face_background), background, _ADJ6)
    one_hole = (face_background != 0) & ((face_background & ~reached) == 0)
    return one_object & one_hole



def thin_to_curves(mask: np.ndarray, distance: np.ndarray, step: float, keep_end_above: float, keep=None) -> np.ndarray:
    """Distance-ordered homotopic thinning of a voxel mask to one-voxel-wide curves.

    Voxels are peeled in order of increasing distance to the wall (levels
    ``step`` apart), so what remains runs along the ridge of the distance field.
    A voxel is removed when it is simple and not the end of a curve; to stay
    topology-preserving while working in parallel, each pass removes voxels of
    one of the 8 parity classes ``(i, j, k) mod 2`` only, which are never
    neighbours of each other (removing them together is the same as removing
    them one by one). Curve ends closer to the wall than ``keep_end_above``
    (one-voxel hairs of a rough mask) are not protected.

    Parameters
    ----------
    mask : 3-D bool array
        The object, with at least one voxel of background on every side.
    distance : float array, shape ``(mask.sum(),)``
        Distance to the wall of each object voxel, in ``np.flatnonzero(mask)`` order.
    step : float
        Distance between peeling levels.
    keep_end_above : float
        Curve ends at least this far from the wall are kept.
    keep : bool array, shape ``(mask.sum(),)``, optional
        Voxels never removed (anchors: the skeleton reaches them), in ``distance``'s order.

    Returns
    -------
    bool array like ``mask``
        The curve skeleton: same connected components and cycles as ``mask``.
    """
    shape = mask.shape
    alive = np.ascontiguousarray(mask, dtype=np.uint8).ravel().copy()
    strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
    neighbour_offset = _OFFSETS26 @ strides
    face_offset = np.array([s * d for s in strides for d in (-1, 1)], dtype=np.int64)
    voxels = np.flatnonzero(alive)
    distance = np.asarray(distance, float)
    order = np.argsort(distance, kind="stable")
    voxels, distance = voxels[order], distance[order]
    kept = np.zeros(len(voxels), bool) if keep is None else np.asarray(keep, bool)[order]
    ijk = np.stack(np.unravel_index(voxels, shape), axis=1)
    parity = (ijk[:, 0] % 2) * 4 + (ijk[:, 1] % 2) * 2 + (ijk[:, 2] % 2)
    bits = np.left_shift(np.uint32(1), np.arange(26, dtype=np.uint32))
    level = distance[0] if len(distance) else 0.0
    top = distance[-1] if len(distance) else 0.0
    pool = np.zeros(0, np.int64)  # indices into ``voxels`` that are alive and reached
    reached = 0
    while True:
        level += step
        upto = int(np.searchsorted(distance, level, side="right"))
        pool = np.concatenate([pool, np.arange(reached, upto)])
        reached = upto
        while True:
            removed = 0
            for cls in range(8):
                cand = pool[parity[pool] == cls]
                if len(cand) == 0:
                    continue
                lin = voxels[cand]
                # only border voxels can be simple
                border = (alive[lin[:, None] + face_offset[None, :]] == 0).any(axis=1)
                cand, lin = cand[border], lin[border]
                if len(cand) == 0:
                    continue
                nb = alive[lin[:, None] + neighbour_offset[None, :]].astype(bool)
                codes = np.bitwise_or.reduce(np.where(nb, bits[None, :], np.uint32(0)), axis=1)
                count = nb.sum(axis=1)
                curve_end = (count == 1) & (distance[cand] >= keep_end_above)
                remove = simple_points(codes) & ~curve_end & (count > 0) & ~kept[cand]
                alive[lin[remove]] = 0
                removed += int(remove.sum())
            pool = pool[alive[voxels[pool]] == 1]
            if removed == 0:
                break
        if reached >= len(voxels) and level > top:
            break
    return alive.reshape(shape).astype(bool)



def flat_ridge_voxels(mask: np.ndarray, distance: np.ndarray, slope: float, keep_end_above: float) -> np.ndarray:
    """Which inside voxels (``np.flatnonzero(mask)`` order) lie on a flat ridge of the
    distance: at least ``keep_end_above`` from the wall, and no neighbour's distance higher
    by more than ``slope`` times the step to it (``distance`` and steps in voxels; a voxel
    outside counts as distance 0). Along a vessel's axis the distance is flat; off it, it
    falls about one for one towards the wall."""
    inside = np.flatnonzero(mask)
    grid = np.zeros(mask.size)
    grid[inside] = distance
    strides = np.array([mask.shape[1] * mask.shape[2], mask.shape[2], 1], dtype=np.int64)
    step = np.linalg.norm(_OFFSETS26, axis=1)
    higher = np.max((grid[inside[:, None] + (_OFFSETS26 @ strides)[None, :]] - distance[:, None]) / step[None, :], axis=1)
    return (higher <= slope) & (distance >= keep_end_above)


def unexplained_ridge_anchors(mask: np.ndarray, distance: np.ndarray, thin: np.ndarray, ridge: np.ndarray) -> np.ndarray:
    """One anchor voxel per 26-connected patch of flat-ridge voxels (``ridge``) that lies
    outside every inscribed ball of the skeleton ``thin`` and beside it (its nearest skeleton
    voxel not a curve end: past an end lies the vessel's own end, which the end placement
    reaches): the patch's voxel farthest from the skeleton. In ``np.flatnonzero(mask)``
    order; ``distance`` in voxels.

    A short stub on a wider parent has no local maximum of the distance (it rises all the
    way from the stub's end into the parent), so the distance-ordered thinning peels its
    end as fast as its sides and the stub goes as a bump before its axis is a curve with an
    end to protect (docs/coverage.md, ridge anchors). Its axis is a flat ridge all the same, and
    one the skeleton's balls leave out: anchored, the thinning keeps a curve to it."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    inside = np.argwhere(mask)
    anchors = np.zeros(len(inside), bool)
    skel = np.argwhere(thin)
    cand = np.flatnonzero(ridge)
    if len(skel) == 0 or len(cand) == 0:
        return anchors
    skel_d = distance[np.searchsorted(np.flatnonzero(mask), np.ravel_multi_index(skel.T, mask.shape))]
    tree = cKDTree(skel)
    near, near_index = tree.query(inside[cand])
    reach = float(skel_d.max())
    # inside a ball: some skeleton voxel within its own distance (pairs within the largest)
    balls = tree.query_ball_point(inside[cand], reach)
    owner = np.repeat(np.arange(len(cand)), [len(b) for b in balls])
    q = np.fromiter(itertools.chain.from_iterable(balls), np.int64, len(owner))
    within = np.linalg.norm(skel[q] - inside[cand][owner], axis=1) <= skel_d[q]
    covered = np.bincount(owner[within], minlength=len(cand)) > 0
    # beyond a curve end (its nearest skeleton voxel an end) lies a vessel's own end, which
    # the end placement reaches; only a ridge beside the skeleton is a side protrusion
    beside = tree.query_ball_point(skel[near_index], 1.8, return_length=True) - 1 >= 2  # 26-neighbours within 1.8 voxels
    left_out = ~covered & beside
    out = cand[left_out]
    if len(out) == 0:
        return anchors
    patch = np.zeros(mask.shape, bool)
    patch[tuple(inside[out].T)] = True
    labels, _ = ndimage.label(patch, structure=np.ones((3, 3, 3)))
    lab = labels[tuple(inside[out].T)]
    # per patch, its voxel farthest from the skeleton (the first of each label, far first)
    order = np.lexsort((-near[left_out], lab))
    first = order[np.r_[True, lab[order][1:] != lab[order][:-1]]]
    anchors[out[first]] = True
    return anchors


def voxel_skeleton(mask: np.ndarray, sdf: SdfFunction, grid: "VoxelGrid", ridge_slope: float = 0.0) -> np.ndarray:
    """Indices ``(k, 3)`` of the curve skeleton of ``mask``.

    The mask is cropped to its bounding box (plus a one-voxel margin), cavities
    are filled (they would leave closed medial surfaces), the SDF is evaluated
    at the inside voxels and the mask is thinned in distance order
    (:func:`thin_to_curves`).

    skimage's Lee thinning is not used: it deletes whole straight branches whose
    section thins to two voxels (scikit-image issue #3757), which happens for
    vessels aligned with the grid.
    """
    occupied = [np.flatnonzero(mask.any(axis=axes)) for axes in ((1, 2), (0, 2), (0, 1))]
    if any(len(o) == 0 for o in occupied):
        return np.zeros((0, 3), np.int64)
    lo = np.array([o[0] for o in occupied])
    hi = np.array([o[-1] for o in occupied]) + 1
    crop = np.zeros(tuple(hi - lo + 2), dtype=bool)
    crop[1:-1, 1:-1, 1:-1] = mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    crop = fill_cavities(crop)
    inside = np.argwhere(crop) + lo - 1  # C order = np.flatnonzero order
    distance = evaluate_sdf(sdf, grid.points(inside))
    thin = thin_to_curves(crop, distance, step=0.5 * grid.spacing, keep_end_above=grid.spacing)
    if ridge_slope > 0:
        # opt-in: thin again, anchored at the flat ridges the first skeleton's balls leave out
        ridge = flat_ridge_voxels(crop, distance / grid.spacing, ridge_slope, 1.0)
        anchors = unexplained_ridge_anchors(crop, distance / grid.spacing, thin, ridge)
        if anchors.any():
            thin = thin_to_curves(crop, distance, step=0.5 * grid.spacing, keep_end_above=grid.spacing, keep=anchors)
    return np.argwhere(thin).astype(np.int64) + lo - 1

