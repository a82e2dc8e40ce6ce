"""A hand-built O-grid block structure of a straight cylinder (for testing the mesher alone)."""

import numpy as np

# duplicates: an import list like blocks/assemble.py's, no shared logic
from vmesh.blocks import (
    AXIS_ALONG,
    AXIS_AROUND,
    AXIS_CORE,
    AXIS_LAYER,
    AXIS_RING,
    FACE_INTERIOR,
    FACE_WALL,
    LAYER_BOUNDARY,
    LAYER_CORE,
    LAYER_RING,
    BlockStructure,
)


def cylinder_blocks(radius=2.0, length=10.0, sections=5, core=0.35, layer=0.2):
    """O-grid (2x2 core, 8 ring and 8 boundary-layer blocks) cylinder along z."""
    c = core * radius
    grid = np.array([[x, y] for y in (-c, 0, c) for x in (-c, 0, c)])  # 3x3 core points, index 3*row+col
    loop = [0, 1, 2, 5, 8, 7, 6, 3]  # core boundary, counter-clockwise
    ang = np.arctan2(grid[loop, 1], grid[loop, 0])
    ring = (1 - layer) * radius * np.c_[np.cos(ang), np.sin(ang)]
    wall = radius * np.c_[np.cos(ang), np.sin(ang)]
    pts2 = np.vstack([grid, ring, wall])  # 9 + 8 + 8 = 25 per section
    quads, kinds, layers, wall_face = [], [], [], []
    for a, b, d, e in [(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6), (4, 5, 8, 7)]:
        quads.append((a, b, d, e)); kinds.append((AXIS_CORE, AXIS_CORE)); layers.append(LAYER_CORE); wall_face.append(False)
    for k in range(8):
        k1 = (k + 1) % 8
        quads.append((loop[k], 9 + k, 9 + k1, loop[k1])); kinds.append((AXIS_RING, AXIS_AROUND)); layers.append(LAYER_RING); wall_face.append(False)
    for k in range(8):
        k1 = (k + 1) % 8
        quads.append((9 + k, 17 + k, 17 + k1, 9 + k1)); kinds.append((AXIS_LAYER, AXIS_AROUND)); layers.append(LAYER_BOUNDARY); wall_face.append(True)
    quads = np.array(quads)
    z = np.linspace(0, length, sections)
    V = np.vstack([np.c_[pts2, np.full(25, zz)] for zz in z])
    hexes, fb, ak, lay, seg = [], [], [], [], []
    for s in range(sections - 1):
        for q, kd, ly, w in zip(quads, kinds, layers, wall_face):
            hexes.append(np.r_[q + 25 * s, q + 25 * (s + 1)])
            f = [FACE_INTERIOR] * 6
            if w:
                f[1] = FACE_WALL
            if s == 0:
                f[4] = 1
            if s == sections - 2:
                f[5] = 2
            fb.append(f)
            ak.append((kd[0], kd[1], AXIS_ALONG))
            lay.append(ly)
            seg.append(s)
    nb = len(hexes)
    on_surface = np.zeros(len(V), bool)
    on_surface[np.arange(sections)[:, None] * 25 + 17 + np.arange(8)] = True
    return BlockStructure(
        vertices=V, hexes=np.array(hexes), vertex_on_surface=on_surface, face_boundary=np.array(fb),
        axis_kind=np.array(ak), block_radius=np.full(nb, radius), block_node=np.array(seg),
        block_segment=np.array(seg), block_layer=np.array(lay), boundary_names={0: "wall", 1: "inlet", 2: "outlet_1"},
    )


def project_cylinder(radius):
    def project(p):
        p = np.asarray(p, float).copy()
        r = np.linalg.norm(p[:, :2], axis=1, keepdims=True)
        p[:, :2] *= radius / np.maximum(r, 1e-300)
        return p
    return project


def cylinder_wall_normals(p):
    """Inward normals of a cylinder wall about the z axis."""
    n = -np.c_[p[:, :2], np.zeros(len(p))]
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def optimiser_constraints(sm, radius):
    """Keyword arguments of :func:`vmesh.geometry.optimize.optimise` for a transfinite mesh of
    :func:`cylinder_blocks`: wall nodes on the cylinder, cap nodes in their z-planes, every
    boundary node marked."""
    n = len(sm.points)
    boundary = np.zeros(n, bool)
    boundary[sm.boundary_faces.ravel()] = True
    caps = np.zeros(n, bool)
    cap_normals = np.zeros((n, 3))
    for bid in (1, 2):
        ids = np.unique(sm.boundary_faces[sm.boundary_ids == bid])
        caps[ids] = True
        cap_normals[ids] = [0.0, 0.0, 1.0]
    return dict(wall=sm.on_wall, wall_normals=cylinder_wall_normals, project=project_cylinder(radius), cap_nodes=caps, cap_normals=cap_normals, boundary=boundary)
