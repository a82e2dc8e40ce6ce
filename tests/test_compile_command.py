"""``vmesh compile``: its generated tube is a valid closed vessel, and the command runs the chain."""

import numpy as np
import pytest

from vmesh.commands.compile import capped_tube
from vmesh.geometry.topology import boundary_edges


def test_capped_tube_is_closed_and_outward():
    surface, skeleton = capped_tube()
    assert len(boundary_edges(surface.faces)) == 0
    v, f = surface.vertices, surface.faces
    volume = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    exact = np.pi * 2.0**2 * 24.0
    assert 0.98 * exact < volume < exact  # outward (positive) and the inscribed polygonal tube
    assert skeleton.n_nodes == 13 and "inlet" in skeleton.node_tags[0] and "outlet" in skeleton.node_tags[-1]


@pytest.mark.slow
def test_compile_command_runs_the_default_chain(capsys):
    from vmesh.cli import main

    assert main(["compile"]) == 0
    out = capsys.readouterr().out
    assert "kernel specialisations" in out


def test_compile_covers_the_parallel_surface_queries():
    """The tube's chain queries fewer than ``bvh.PARALLEL_MIN`` points at once (serial
    kernels); ``vmesh compile`` also runs the parallel sign and ray kernels a real vessel's
    first run needs, and their answers agree with the serial ones."""
    from vmesh.commands.compile import _warm_parallel_queries
    from vmesh.geometry import bvh
    from vmesh.geometry.sdf import SignedDistance

    surface, _ = capped_tube()
    _warm_parallel_queries(surface)
    assert len(bvh._signs_kernel.overloads) >= 1 and len(bvh._line_kernel.overloads) >= 1
    sdf = SignedDistance.from_surface(surface)
    z = np.linspace(3.0, 21.0, bvh.PARALLEL_MIN)
    axis = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])  # 2 inside the wall, far from the caps
    whole = sdf.distance(axis)  # one parallel query
    serial = np.concatenate([sdf.distance(axis[i : i + 1000]) for i in range(0, len(z), 1000)])
    np.testing.assert_allclose(whole, serial, rtol=1e-12)  # a tie may take the other triangle: last bits
    assert np.all((whole > 1.99) & (whole <= 2.0))  # inside: positive, the inscribed polygon's facets
    moved, hit = sdf.intersect_lines(axis, np.tile([1.0, 0.0, 0.0], (len(z), 1)), 5.0)
    assert hit.all() and np.allclose(np.hypot(moved[:, 0], moved[:, 1]), 2.0, atol=0.01)
