"""Render block structures of the synthetic cases to PNG (``docs/images/blocks_<case>.png``).

Usage::

    python docs/render_blocks.py [CASE ...] [--out docs/images]

Each image shows the vessel surface (translucent), the block edges coloured by layer
(core, ring, boundary layer) and the wall corners, from two viewpoints side by side.
Default cases: y_bifurcation, five_furcation, aneurysm, coarctation.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

DEFAULT_CASES = ("y_bifurcation", "five_furcation", "aneurysm", "coarctation")
LAYER_COLORS = {0: "#1f77b4", 1: "#2ca02c", 2: "#d62728"}


def build_case(case: str, **options):
    """Surface, caps and block structure of a synthetic case (default options)."""
    from data_synthetic.generate import case_paths
    from vmesh.context import Context
    from vmesh.geometry.block_builder import BlockOptions, build_blocks
    from vmesh.geometry.sdf import SignedDistance
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface
    from vmesh.registry import get_filter

    surface_path, skeleton_path = case_paths(case)
    ctx = Context(surface=read_surface(surface_path))
    get_filter("detect_caps")(ctx)
    sdf = SignedDistance.from_surface(ctx.surface)
    blocks = build_blocks(read_skeleton(skeleton_path), sdf.distance, ctx.caps, BlockOptions(**options))
    return ctx.surface, blocks


def block_edge_lines(blocks, layer: int | None = None):
    """A pyvista PolyData of the unique block edges (optionally of one layer only)."""
    import pyvista as pv

    from vmesh.blocks import HEX_EDGES

    H = blocks.hexes if layer is None else blocks.hexes[blocks.block_layer == layer]
    e = np.unique(np.sort(H[:, HEX_EDGES].reshape(-1, 2), axis=1), axis=0)
    lines = np.hstack([np.full((len(e), 1), 2), e]).ravel()
    return pv.PolyData(blocks.vertices, lines=lines)


def render_blocks_png(path, surface, blocks, title: str = "", size=(1600, 800)) -> Path:
    """Two views of the block structure inside the translucent surface."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    mesh = pv.PolyData(surface.vertices, np.hstack([np.full((len(surface.faces), 1), 3), surface.faces]).ravel())
    p = pv.Plotter(off_screen=True, window_size=list(size), shape=(1, 2), border=False)
    # look along the direction in which the structure is thinnest, then obliquely
    centre = blocks.vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(blocks.vertices - centre, full_matrices=False)
    span = np.ptp(blocks.vertices, axis=0).max()
    views = [axes[2], axes[2] * np.cos(0.9) + axes[1] * np.sin(0.9)]
    for col, view in enumerate(views):
        p.subplot(0, col)
        p.add_mesh(mesh, color="#d9d9d9", opacity=0.18)
        for layer, color in LAYER_COLORS.items():
            lines = block_edge_lines(blocks, layer)
            if lines.n_cells:
                p.add_mesh(lines, color=color, line_width=1.6 if layer == 2 else 1.2)
        wall = blocks.vertices[blocks.vertex_on_surface]
        p.add_points(wall, color="black", point_size=4, render_points_as_spheres=True)
        p.camera.focal_point = centre
        p.camera.position = centre + 3.0 * span * view
        p.camera.up = axes[0] if col == 0 else axes[0]
        p.reset_camera()
        p.camera.zoom(1.1)
        if col == 0 and title:
            p.add_text(title, font_size=11, color="black")
    p.set_background("white")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    p.screenshot(str(path))
    p.close()
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=list(DEFAULT_CASES))
    ap.add_argument("--out", default=str(ROOT / "docs" / "images"))
    args = ap.parse_args(argv)
    for case in args.cases:
        surface, blocks = build_case(case)
        info = blocks.info
        title = (
            f"{case}: {blocks.n_blocks} blocks, {info['blocks_around']} around "
            f"(core {info['core'][0]}x{info['core'][1]}), max twist {info['max_twist_deg']:.1f} deg\n"
            "blue core, green ring, red boundary layer, black: corners on the wall"
        )
        out = render_blocks_png(Path(args.out) / f"blocks_{case}.png", surface, blocks, title)
        print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
