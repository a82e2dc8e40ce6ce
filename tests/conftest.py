import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # data_synthetic is importable from the checkout

from vmesh import realdata  # noqa: E402

SYNTHETIC = ROOT / "data_synthetic"

from data_synthetic.generate import CASES as SYNTHETIC_CASES  # noqa: E402  (every synthetic case, by name)


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels():
    """Compile (or load) vmesh's numba kernels once, in this process, before any test
    starts CLI runs or Dask workers: on a fresh checkout those would otherwise all compile
    the same kernels at once and write numba's cache beside the sources together.

    When the optimiser's kernels are not cached (a fresh clone, or new kernel sources), first
    ``vmesh compile``'s own pass (the default chain on a small tube, the optimiser's kernels in
    a background child meanwhile): without it the optimiser's, the worst pass's and the ray
    crossings' kernels were compiled by the first Dask workers, each of the two on its own
    (session 26: ~20 s CPU each). With them cached the pass is left out: it would only load
    kernels the tests load anyway, and cost the fast lane ~1 s CPU."""
    from vmesh.commands.compile import compile_kernels, optimiser_cached

    if not optimiser_cached():
        compile_kernels()
    import numpy as np

    from vmesh.geometry.quality import hex8_scaled_jacobian
    from vmesh.geometry.sdf import SignedDistance

    tetra = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    sdf = SignedDistance(tetra, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    from vmesh.geometry.bvh import PARALLEL_MIN

    for n in (1000, PARALLEL_MIN):  # the serial and the parallel kernels
        sdf.project(np.random.default_rng(0).random((n, 3)))  # BVH build and query, Morton codes, signs
        sdf.intersect_lines(np.full((n, 3), 0.2), np.random.default_rng(1).normal(size=(n, 3)), 1.0)
    cube = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], float)
    hex8_scaled_jacobian(cube, np.arange(8)[None])
    # transfinite kernels: a graded cylinder runs every one of them with mesh_blocks' types
    from cylinder_blocks import cylinder_blocks, project_cylinder
    from vmesh.geometry.transfinite import Refinement, coons_patch, mesh_blocks, regrade_lines, transfinite_volume

    mesh_blocks(cylinder_blocks(radius=2.0, sections=2), project_cylinder(2.0), Refinement(first_layer=0.05, order=2))
    lattice = np.random.default_rng(0).random((1, 3, 3, 3, 3))
    transfinite_volume(lattice)
    coons_patch(lattice[:, :, :, 0])
    regrade_lines(lattice, 1, np.ones(1, bool), np.full(1, 0.1), 2, 1, "gauss_lobatto")


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


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With ``VMESH_TEST_TIMES=FILE``, append each test's wall and CPU seconds (setup, call
    and teardown; all threads) to FILE as it finishes: on a shared, loaded machine the CPU
    time tells which tests belong in the slow lane better than the wall time does."""
    import os
    import resource
    import time

    def cpu():  # this process's threads and its finished child processes (Dask workers, CLI runs)
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + children.ru_utime + children.ru_stime

    path = os.environ.get("VMESH_TEST_TIMES")
    wall, cpu0 = time.perf_counter(), cpu()
    yield
    if path:
        with open(path, "a") as f:
            f.write(f"{time.perf_counter() - wall:.2f}\t{cpu() - cpu0:.2f}\t{item.nodeid}\n")
