import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # data_synthetic is importable from the checkout

from vmesh import realdata  # noqa: E402

SYNTHETIC = ROOT / "data_synthetic"

from data_synthetic.generate import CASES as SYNTHETIC_CASES  # noqa: E402  (every synthetic case, by name)


@pytest.fixture(scope="session")
def real_path():
    """``real_path(name)`` -> path of a real data file; skips (with the reason) when absent."""

    def get(name):
        p = realdata.real_file(name)
        if p is None:
            reason = realdata.missing_reason() if realdata.real_data_dir() is None else f"real data file {name} not found"
            print(f"SKIP: {reason}")
            pytest.skip(reason)
        return p

    return get


def synthetic_case(name):
    """(surface path, skeleton path) of a committed synthetic case."""
    return SYNTHETIC / name / "surface.ply", SYNTHETIC / name / "skeleton.json"


@pytest.fixture(scope="session")
def y_run(tmp_path_factory):
    """A finished run folder of the default chain on the synthetic Y-bifurcation (p = 1)."""
    from vmesh.chain import FilterChain

    surface, skeleton = synthetic_case("y_bifurcation")
    out = tmp_path_factory.mktemp("y_run") / "run"
    FilterChain.load("default").run(surface=surface, skeleton=skeleton, out_dir=out)
    return out
