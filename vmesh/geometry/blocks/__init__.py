"""Block structures of vessels: conforming hexahedral blocks from a skeleton and a signed distance.

Modules: :mod:`.builder` (:func:`build_blocks` and the builder that runs the steps),
:mod:`.options` (:class:`BlockOptions` in groups, and the per-junction and per-branch state),
:mod:`.state` (the builder's mutable state, by concern),
:mod:`.prep` (skeleton preparation: splitting and merging junctions, caps, section spacing),
:mod:`.junctions`, :mod:`.sections`, :mod:`.assemble` and :mod:`.repair` (the builder's steps)
and :mod:`.checks` (wall-projected and filled quality, invalid blocks, failures).
"""

from .builder import build_blocks
from .checks import (
    FILL_CHECKS,
    block_structure_checks,
    fill_quality,
    fill_score,
    projected_wall_quality,
    write_bad_blocks,
)
from .options import CLOSED, CYCLE, JUNCTION, OPEN, BlockOptions, EndOptions, JunctionOptions, LastTryOptions, RepairOptions, SectionOptions
from ..skeleton.graph import polyline_at
from .prep import (
    endpoint_caps,
    merge_junction_pair,
    redistribute_sections,
    split_nonplanar_junctions,
)

__all__ = [
    "BlockOptions", "SectionOptions", "JunctionOptions", "EndOptions", "RepairOptions", "LastTryOptions", "build_blocks", "FILL_CHECKS", "block_structure_checks", "fill_quality", "fill_score",
    "projected_wall_quality", "write_bad_blocks", "endpoint_caps", "merge_junction_pair", "polyline_at",
    "redistribute_sections", "split_nonplanar_junctions", "JUNCTION", "OPEN", "CLOSED", "CYCLE",
]
