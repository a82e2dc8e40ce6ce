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
