"""Bounded work for the block builder: rays cast once per build, and a budget of assemblies.

Every fix round re-assembles the whole block structure, and every changed skeleton that
:func:`~vmesh.geometry.blocks.builder.build_blocks` tries starts a new builder; both used
to cast every section's rays again, so a tree of thousands of sections that fails at one
junction spent minutes casting the same rays. :class:`RayCache` keeps each ray's result
(rays depend only on their origin, direction, scale and reach, so a section that did not
move is cast once per build; the cache lives beside
:func:`~vmesh.geometry.rays.cast_rays`, which the skeleton's bend thinning uses
too), and :class:`WorkBudget` bounds the number of assemblies a
build may do, so that a structure that cannot be made valid fails after a fixed multiple
of one assembly's work instead of after every try.
"""

from __future__ import annotations

from ..rays import RayCache


class WorkBudget:
    """Assemblies of the whole block structure one :func:`build_blocks` call may do, over
    all its fix rounds and changed skeletons.

    One assembly costs time in proportion to the tree, so a budget counted in assemblies
    bounds a build by a fixed multiple of the tree's size, however many junctions fail.

    Parameters
    ----------
    assemblies : int
        The budget; ``0`` for none.
    """

    def __init__(self, assemblies: int = 0):
        self.limit = int(assemblies)
        self.used = 0
        self.valid_after = None  # assemblies spent when the blocks were first all valid
        self.rays = RayCache()
        self.bend_rounds = False  # the extra budget the bend-drop rounds share (builder._without_bends)

    @property
    def spent(self) -> bool:
        """True once the budget is used up."""
        return self.limit > 0 and self.used >= self.limit

    def charge(self) -> None:
        """Count one assembly."""
        self.used += 1

    def stop_note(self) -> str:
        """What the error of a failed build adds when the budget stopped it ("" otherwise)."""
        if not self.spent:
            return ""
        return (f"; stopped after {self.used} assemblies of the block structure (build_block_structure.work_budget "
                f"= {self.limit}: a larger budget lets more fixes and changed skeletons be tried)")

    def summary(self) -> dict:
        """What the build spent: assemblies (``valid_after``: those until every block was valid;
        the rest relieve wall folds, bounded by the options), the budget, rays cast and reused."""
        return {"assemblies": self.used, "valid_after": self.valid_after, "work_budget": self.limit,
                "rays_cast": self.rays.misses, "rays_reused": self.rays.hits}

