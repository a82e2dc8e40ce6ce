"""Names of element labels and boundary patches, the same in every export format.

Element labels name *regions* of the vessel (``vessel``, ``aneurysm``, user tags); the open
ends and the wall are *boundaries* (``wall``, ``inlet``, ``outlet_1`` ...) and name boundary
patches only. Names are made of letters, digits and ``_`` so that VTU, Gmsh, Abaqus, Exodus
and OpenFOAM all carry them unchanged; a label never shares a name with a boundary, so the
Gmsh volume and surface physical groups have distinct names.
"""

from __future__ import annotations

import re

import numpy as np

#: Tags that name open ends or the wall (``inlet``, ``outlet``, ``inlet_2``, ``outlet_1``,
#: ``wall``) or the kind of a skeleton end (``cap_end``, ``flat_end``, ``rounded_end``).
BOUNDARY_TAG = re.compile(r"^((inlet|outlet|wall)(_?\d+)?|[a-z]+_end)$", re.IGNORECASE)


def clean_name(name: str) -> str:
    """``name`` with every character other than a letter, digit or ``_`` made ``_``,
    starting with a letter (``g_`` prefixed otherwise)."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", str(name)).strip("_") or "g"
    return s if s[0].isalpha() else f"g_{s}"


def label_names(block_tags, boundary_names, untagged: str = "vessel") -> list[str]:
    """The label name of each block from its tags.

    Inlet/outlet/wall tags and the boundary names are dropped (they name patches), so is
    ``untagged`` when another tag remains; the rest are cleaned and joined by ``_`` in sorted
    order (``aneurysm_neck``); a block with nothing left is ``untagged``.
    """
    boundaries = {str(n).lower() for n in boundary_names}
    base = clean_name(untagged)
    out = []
    for tags in block_tags:
        kept = sorted({clean_name(t) for t in tags if not BOUNDARY_TAG.match(str(t)) and str(t).lower() not in boundaries})
        kept = [t for t in kept if t != base and t.lower() not in boundaries] or [base]
        out.append("_".join(kept))
    return out


def distinct_volume_names(label_names: dict, boundary_names) -> dict:
    """``{label id: name}`` with any name that a boundary also has suffixed ``_volume``
    (meshes labelled before labels were cleaned), so no two physical groups share a name."""
    taken = {str(n).lower() for n in boundary_names}
    return {k: (f"{v}_volume" if str(v).lower() in taken else str(v)) for k, v in label_names.items()}


def names_table(mesh) -> list[dict]:
    """Every element label and boundary with its id, count and name in each export format."""
    from .export import boundary_groups, cell_labels

    labels, lnames = cell_labels(mesh)
    bnames = boundary_groups(mesh)
    vol = distinct_volume_names(lnames, bnames.values())
    counts = dict(zip(*np.unique(labels, return_counts=True)))
    bcounts = dict(zip(*np.unique(np.asarray(mesh.boundary_ids), return_counts=True)))
    rows = []
    for tag, (k, name) in enumerate(lnames.items(), start=1):
        rows.append({
            "name": name, "kind": "elements", "id": int(k), "count": int(counts.get(k, 0)),
            "vtu": f"cell array label = {k}", "msh": f"3D physical group {vol[k]} (tag {tag})", "inp": f"ELSET={name}",
            "exo": f"element block {name}", "openfoam": f"cellZone {name}",
        })
    for tag, (b, name) in enumerate(bnames.items(), start=1):
        rows.append({
            "name": name, "kind": "boundary faces", "id": int(b), "count": int(bcounts.get(b, 0)),
            "vtu": f"boundary.vtp boundary_id = {b}", "msh": f"2D physical group {name} (tag {tag})", "inp": f"SURFACE={name}, NSET={name}",
            "exo": f"side set and node set {name}", "openfoam": f"patch {name} ({'wall' if name == 'wall' else 'patch'})",
        })
    return rows
