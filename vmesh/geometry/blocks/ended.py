"""The section rays' territory ends at the open ends in a contact, as the contact cut does.

:func:`~vmesh.geometry.rays.clip_to_territory` cuts a section ray where it enters another
vessel's tube (spheres about samples along its axis) deeper than its own. At an open end
those spheres reach a radius past the cap, where the vessel no longer is; since h18/cap the
contact cut stops at the plane of such an end (``ContactCuts.open_end``), and the wall
projector keeps the cap where the other vessel's lumen crosses it. A ray of the passing
vessel cut past the plane ended on no surface: its "wall" corner lay inside the lumen and
the mesher took it to the nearest wall (s0 g0015 extracted, node 107: 0.29 past the thick
vessel's cap plane, inside its end sphere; the layer folded there, docs/optimiser.md
h25/inverted). Here the tube of a branch that ends at the open end of a touched cap ends at
that cap's plane.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Tube samples within this many end radii of an open end node are ended at its cap's plane
#: (a sphere about a sample farther back than its own radius cannot reach past the plane;
#: two radii leave room for a branch whose radius grows towards its end)
END_REACH = 2.0


def ended_at_touched_caps(territory, topo, cap_of: dict, touched) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """``ended(points, samples)`` for :func:`~vmesh.geometry.rays.clip_to_territory`: True
    where a tube sample belongs to a branch that ends at an open end whose cap is in
    ``touched`` (cap ids) and the point lies past that cap's plane (on the side its outward
    normal points to). None when no such end (every ray cut as before).

    Parameters
    ----------
    territory : :class:`~.prep.Territory`
        The tube samples (``Q``), their radii and nearest skeleton nodes (``q_node``).
    topo
        The builder's topology: ``branches``, node positions ``pos`` and ``sk.radii``.
    cap_of : dict
        Endpoint node -> its cap (``center``, outward ``normal``, ``id``).
    touched : iterable of int
        Ids of the caps of open ends in a contact.
    """
    touched = {int(t) for t in touched or ()}
    if not touched:
        return None
    planes = []
    for end, cap in cap_of.items():
        if int(cap.id) not in touched:
            continue
        nodes = next((br.nodes for br in topo.branches if int(end) in (int(br.nodes[0]), int(br.nodes[-1]))), None)
        if nodes is None:
            continue
        # the branch's other terminal (a junction) is left out: samples nearest it may lie on a
        # sibling's tube, which does not end at this cap (a branch shorter than END_REACH radii)
        other = int(nodes[0]) if int(end) == int(nodes[-1]) else int(nodes[-1])
        nodes = [int(n) for n in nodes if int(n) != other]
        near = np.isin(territory.q_node, nodes) & (np.linalg.norm(territory.Q - topo.pos[int(end)], axis=1) <= END_REACH * topo.sk.radii[int(end)])
        if near.any():
            n = np.asarray(cap.normal, float)
            planes.append((near, np.asarray(cap.center, float), n / np.linalg.norm(n)))
    if not planes:
        return None

    def ended(points: np.ndarray, samples: np.ndarray) -> np.ndarray:
        out = np.zeros(len(samples), bool)
        for near, centre, normal in planes:
            out |= near[samples] & ((points - centre) @ normal > 0.0)
        return out

    return ended
