"""Block structures from a skeleton and a signed distance: kept for imports of
``vmesh.geometry.block_builder``; the code lives in :mod:`vmesh.geometry.blocks`."""

from .blocks import (  # noqa: F401
    CLOSED,
    CYCLE,
    FILL_CHECKS,
    JUNCTION,
    OPEN,
    BlockOptions,
    block_structure_checks,
    build_blocks,
    endpoint_caps,
    fill_quality,
    fill_score,
    merge_junction_pair,
    polyline_at,
    projected_wall_quality,
    redistribute_sections,
    split_nonplanar_junctions,
    write_bad_blocks,
)
from .blocks.builder import _Builder  # noqa: F401
from .blocks.checks import _Failure  # noqa: F401
from .blocks.options import _Branch, _Junction  # noqa: F401
