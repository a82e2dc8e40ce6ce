"""Locate the real vessel data set (not shipped with vmesh).

Looks at ``$VMESH_REAL_DATA``, then ``../shared/data/real`` next to the source
checkout and the working directory. Tests and benchmarks skip, printing the
reason, when neither exists.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

#: Real cases: surface file, centerline file (or None), number of open ends.
REAL_CASES = {
    "carotid": ("carotid_vmtk.vtp", "carotid_vmtk_centerline.vtp", 0),
    "aorta_simvascular": ("aorta_simvascular_demo.vtp", "aorta_simvascular_demo_centerlines.vtp", 0),
    "coarctation": ("coarctation_bpm120_open.stl", None, 5),
    "aneurysm": ("aneurysm_ica_aneurisk_c0015_open.vtp", None, 3),
    "thoracic_aorta": ("thoracic_aorta_open.vtp", "thoracic_aorta_centerlines.vtp", 6),
    "ica_swc": ("ica_swc_surface.vtp", "ica_centerline.swc", 0),
}


@dataclass(frozen=True)
class RealCase:
    """One real surface of the data set (see PROVENANCE.md there).

    Attributes
    ----------
    surface : str
        File name of the surface (a triangle surface, or a volume mesh whose boundary is the wall).
    centerline : str or None
        File name of its centerline (VMTK/SimVascular VTP or SWC), ``None`` when there is none.
    open_ends : int
        Number of open boundary loops of the surface (0: closed or capped).
    units : str
        Length unit of the coordinates: ``"mm"``, ``"cm"``, ``"m"`` or ``"unclear"``.
    components : int
        Connected pieces of the surface.
    volume_mesh : bool
        The file is a volume mesh; its boundary surface is the vessel wall.
    note : str
        What makes the case hard.
    """

    surface: str
    centerline: str | None = None
    open_ends: int = 0
    units: str = "mm"
    components: int = 1
    volume_mesh: bool = False
    note: str = ""


#: Every real surface in the data set, with its centerline where there is one.
#: A superset of :data:`REAL_CASES` (same keys for the six cases listed there).
REAL_CORPUS: dict[str, RealCase] = {
    "carotid": RealCase("carotid_vmtk.vtp", "carotid_vmtk_centerline.vtp", 0,
                        note="VMTK centerline: overlapping polylines"),
    "aorta_simvascular": RealCase("aorta_simvascular_demo.vtp", "aorta_simvascular_demo_centerlines.vtp", 0,
                                  note="SimVascular centerline graph, ModelFaceID caps"),
    "coarctation": RealCase("coarctation_bpm120_open.stl", None, 5, note="arch with 3 branches, narrowing"),
    "aneurysm": RealCase("aneurysm_ica_aneurisk_c0015_open.vtp", None, 3, note="triangles and quads, saccular bulge"),
    "thoracic_aorta": RealCase("thoracic_aorta_open.vtp", "thoracic_aorta_centerlines.vtp", 6,
                               note="inward normals; centerline stops short of the descending end"),
    "ica_swc": RealCase("ica_swc_surface.vtp", "ica_centerline.swc", 0, note="fine surface (150k triangles), SWC"),
    "glenn_pa": RealCase("svfsi_pa_glenn_wall.vtp", None, 21, note="21 open ends, LPA stenosis"),
    "dorv_aorta": RealCase("dorv_p1_aorta.vtp", None, 0, note="closed aorta with arch branches"),
    "dorv_pa": RealCase("dorv_p1_pa.vtp", None, 0, note="closed pulmonary trunk, short wide branches"),
    "sphinx_carotid": RealCase("sphinx_carotid.stl", None, 0, note="capped carotid bifurcation"),
    "dfem_coronary": RealCase("dfem_coronary_tree.stl", None, 0, note="capped coronary tree, 6 outlets"),
    "feelpp_aneurysm": RealCase("feelpp_aneurysm.stl", None, 3, units="unclear",
                                note="saccular aneurysm at a bifurcation"),
    "sv_rpa": RealCase("sv_rpa_su201.vtp", "sv_rpa_su201_cl.vtp", 0, note="capped RPA subtree, SimVascular centerline"),
    "gmsh_carotid": RealCase("gmsh_carotid_bif.stl", None, 3, units="cm", note="carotid bulb in cm"),
    "hepatic_artery": RealCase("hepatic_artery.stl", None, 0, components=2, note="two connected pieces"),
    "kd_lima": RealCase("kd_lima_mesh.vtu", "kd_lima_cl.vtp", 0, units="cm", volume_mesh=True,
                        note="tetrahedral volume mesh input, tortuous graft"),
    "brava_BG0002": RealCase("brava_BG0002_surface.vtp", "brava_BG0002.swc", 0,
                             note="whole-brain tree, ~3,000 SWC nodes, 400k triangles"),
}


def real_data_dir() -> Path | None:
    """The folder holding the real data set, or ``None``."""
    env = os.environ.get("VMESH_REAL_DATA")
    candidates = [Path(env)] if env else []
    repo = Path(__file__).resolve().parent.parent
    candidates += [repo.parent / "shared" / "data" / "real", Path.cwd().parent / "shared" / "data" / "real"]
    for c in candidates:
        if c.is_dir() and any(c.iterdir()):
            return c
    return None


def real_file(name: str) -> Path | None:
    """Path of one real data file, or ``None`` when the data set or the file is absent."""
    d = real_data_dir()
    if d is None:
        return None
    p = d / name
    return p if p.exists() else None


def missing_reason() -> str:
    return "real vessel data not found: set $VMESH_REAL_DATA or place it in ../shared/data/real"


def real_corpus(names=None) -> list[tuple[str, Path, Path | None, RealCase]]:
    """The cases of :data:`REAL_CORPUS` whose files are present.

    Parameters
    ----------
    names : iterable of str, optional
        Keep only these keys (default: every case).

    Returns
    -------
    list of (key, surface path, centerline path or None, RealCase)
        Cases whose surface file is missing are left out; a missing centerline file gives ``None``.
    """
    out = []
    for key, case in REAL_CORPUS.items():
        if names is not None and key not in names:
            continue
        surface = real_file(case.surface)
        if surface is None:
            continue
        centerline = real_file(case.centerline) if case.centerline else None
        out.append((key, surface, centerline, case))
    return out
