"""Where a branch's sections are clear of its junction (issue 17, hepatic_artery extracted).

``_Sections._clearance`` walks out from each junction along each branch and puts the
branch's first section where the rays of every later candidate stay within
``clear_ray_factor`` branch radii of its centre. hepatic_artery's branch 11 -> 576 curls
back 3-4 radii from its 4-junction: the candidates there had long rays again, after a clean
stretch of 2.5 radii, so the first section went past the curl (7.2 along the branch, the end
of the search) and its first blocks spanned the bend's chord (3 blocks invalid in every try,
-0.52). Long rays beyond a clean stretch of a branch radius or more are the branch's own.
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import blebbed_bifurcation
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.blocks import sections
from vmesh.geometry.blocks.sections import _clear_from


def test_clear_from_ends_with_the_junctions_run():
    s = 0.3 * np.arange(1, 25)
    ok = np.array([c == "." for c in "XXXXXXX...........XXXXXX"])
    assert _clear_from(ok, s, 1.2) == 7  # the curl's run beyond 3.3 of clean arc is not the junction's
    # runs parted by less than a radius are one (a noisy wall near the junction)
    ok = np.array([c == "." for c in "XXX..XXX......."])
    assert _clear_from(ok, s[: len(ok)], 1.2) == 8
    assert _clear_from(np.ones(5, bool), s[:5], 1.2) == 0
    assert _clear_from(np.zeros(5, bool), s[:5], 1.2) == 5  # never clear: the end of the search


@pytest.mark.slow
def test_a_bleb_past_a_clean_stretch_leaves_the_first_section_where_it_was(monkeypatch):
    """The blebbed daughter's sections are clear of the junction where its twin's are (1.6
    along it), not past the bleb (4.2 before the change), and the blocks are valid."""
    case = blebbed_bifurcation()
    clear = {}
    measure = sections._Sections._clearance

    def kept(self):
        clear.update(measure(self))
        return clear

    monkeypatch.setattr(sections._Sections, "_clearance", kept)
    blocks = build_blocks(case.skeleton, case.distance, None, BlockOptions(), project=case.project)
    assert blocks.corner_jacobians().min() > 0
    # branches 1 and 2: the upper (blebbed) and lower daughters, from the junction (side 0)
    upper, lower = clear[(1, 0)], clear[(2, 0)]
    assert lower > 0
    assert upper == pytest.approx(lower, abs=0.26)  # one candidate step (a quarter radius)
    assert upper < 2.5  # the bleb sits at 3.5 - 0.7
