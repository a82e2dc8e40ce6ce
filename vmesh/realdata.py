"""Locate the real vessel data set (not shipped with vmesh).

Looks at ``$VMESH_REAL_DATA``, then ``../shared/data/real`` next to the source
checkout and the working directory. Tests and benchmarks skip, printing the
reason, when neither exists.
"""

from __future__ import annotations

import os
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
