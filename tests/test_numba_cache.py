"""vmesh's numba cache is keyed on the kernel sources' content, not on where they are installed
(``vmesh/numba_cache.py``): a second copy of the same sources loads the first one's compiled
kernels, and an edited kernel module is compiled again."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import vmesh

_PROBE = """
import numpy as np
from vmesh.geometry import quality
quality.hex8_scaled_jacobian(np.array([[x, y, z] for z in (0., 1.) for y in (0., 1.) for x in (0., 1.)]), np.arange(8)[None])
s = quality._hex8_kernel.stats
print(sum(s.cache_hits.values()), sum(s.cache_misses.values()))
"""


def _copy(root: Path) -> Path:
    shutil.copytree(Path(vmesh.__file__).parent, root / "vmesh", ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _hits_misses(root: Path, cache: Path) -> tuple[int, int]:
    env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(cache))
    env.pop("VMESH_NUMBA_CACHE", None)
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True, cwd=root)
    hits, misses = map(int, out.stdout.split()[-2:])
    return hits, misses


def test_vmesh_kernels_use_the_content_locator():
    from numba.core.caching import FunctionCache

    from vmesh import numba_cache
    from vmesh.geometry import quality
    from vmesh.geometry.optimize import kernels

    for kernel in (quality._hex8_kernel, kernels.sweep_colour_serial):
        locator = FunctionCache(kernel.py_func)._impl.locator
        assert isinstance(locator, numba_cache.ContentCacheLocator)
        assert locator.get_cache_path() == str(numba_cache.cache_folder(kernel.py_func.__code__.co_filename))


def test_a_kernel_module_digest_covers_the_kernel_modules_it_imports():
    from vmesh import numba_cache

    geometry = numba_cache.PACKAGE / "geometry"
    names = {m: {p.name for p in numba_cache.kernel_closure(str(geometry / m))} for m in ("octree_sdf.py", "transfinite_kernels.py", "quality.py", "bvh.py")}
    assert names == {"octree_sdf.py": {"octree_sdf.py", "bvh.py"}, "transfinite_kernels.py": {"transfinite_kernels.py", "bvh.py"}, "quality.py": {"quality.py"}, "bvh.py": {"bvh.py"}}


_NESTED_IMPORTS = """
import a
if x:
    from . import b
else:
    from .c import d
try:
    import e
except ImportError:
    from vmesh import f
else:
    import g
finally:
    import h
class K:
    def m(self):
        with open(p) as fh:
            for i in r:
                while i:
                    from ..i import j
async def n():
    async with q:
        import o
match v:
    case 1:
        import p2
y = lambda: __import__("not_a_statement")
"""


def test_the_statement_walk_finds_the_imports_ast_walk_finds():
    """The digest's import scan visits statements only (``_statements``): the same import
    statements as a full ``ast.walk``, on nested blocks and on every module of the package,
    so every kernel module keeps its cache folder."""
    import ast

    from vmesh import numba_cache

    def imports(nodes):
        return sorted(ast.dump(n) for n in nodes if isinstance(n, (ast.Import, ast.ImportFrom)))

    nested = ast.parse(_NESTED_IMPORTS)
    assert len(imports(numba_cache._statements(nested))) == 10
    assert imports(numba_cache._statements(nested)) == imports(ast.walk(nested))
    for path in sorted(numba_cache.PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_bytes())
        assert imports(numba_cache._statements(tree)) == imports(ast.walk(tree)), path


@pytest.mark.slow  # three fresh interpreters and a compile: ~10 s
def test_kernels_are_cached_by_source_content_not_path(tmp_path):
    cache = tmp_path / "cache"
    first, second, edited = (_copy(tmp_path / name) for name in ("first", "second", "edited"))
    assert _hits_misses(first, cache) == (0, 1)  # compiled and written
    assert _hits_misses(second, cache) == (1, 0)  # another path, same sources: loaded
    other = edited / "vmesh" / "geometry" / "bvh.py"  # a kernel module the probed one does not import
    other.write_text(other.read_text() + "\n# edited\n")
    assert _hits_misses(edited, cache) == (1, 0)
    mine = edited / "vmesh" / "geometry" / "quality.py"
    mine.write_text(mine.read_text() + "\n# edited\n")
    assert _hits_misses(edited, cache) == (0, 1)  # stale entries are not loaded
    versions = list((cache / "vmesh").iterdir())
    assert len(versions) == 1 and len(list(versions[0].glob("geometry.quality-*"))) == 2  # one folder per source version


def test_prune_keeps_the_newest_source_versions(tmp_path, monkeypatch):
    from numba.core import config

    from vmesh import numba_cache

    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path))
    module = str(numba_cache.PACKAGE / "geometry" / "quality.py")
    base = numba_cache.cache_folder(module).parent
    for i in range(12):
        for name in ("geometry.quality", "geometry.bvh"):
            (base / f"{name}-old{i:02d}").mkdir(parents=True)
            os.utime(base / f"{name}-old{i:02d}", (i, i))
    removed = numba_cache.prune(module, keep=4)
    assert sorted(p.name for p in base.glob("geometry.quality-*")) == ["geometry.quality-old09", "geometry.quality-old10", "geometry.quality-old11"]
    assert len(removed) == 9 and len(list(base.glob("geometry.bvh-*"))) == 12  # other modules' versions stay


def test_no_background_compile_when_the_optimiser_is_cached_or_turned_off(monkeypatch):
    from vmesh.commands import compile as command

    monkeypatch.setattr(command, "optimiser_cached", lambda: True)
    assert command.compile_in_background() is None
    monkeypatch.setattr(command, "optimiser_cached", lambda: False)
    monkeypatch.setenv("VMESH_BACKGROUND_COMPILE", "0")
    assert command.compile_in_background() is None


def _seed_all_but_the_optimiser(cache: Path) -> None:
    """Copy this process's cached kernels of the current sources into ``cache`` (a
    ``$NUMBA_CACHE_DIR``), all but the optimiser's own module (``optimize/kernels.py``):
    a background compile then compiles that module's kernels, not again the structure's,
    trials' and worst pass's ones (and the parallel surface queries') it also loads."""
    from vmesh import numba_cache

    optimiser = numba_cache.cache_folder(str(numba_cache.PACKAGE / "geometry" / "optimize" / "kernels.py"))
    for module in numba_cache.PACKAGE.rglob("*.py"):
        folder = numba_cache.cache_folder(str(module))
        if folder != optimiser and folder.is_dir():
            shutil.copytree(folder, cache / "vmesh" / folder.parent.name / folder.name, ignore=shutil.ignore_patterns("*.lock"))


@pytest.mark.slow  # compiles the optimiser's kernels into a cache without them: ~12 s
def test_background_compile_fills_the_optimiser_cache(tmp_path):
    _seed_all_but_the_optimiser(tmp_path)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("VMESH_BACKGROUND_COMPILE", None)
    probe = "from vmesh.commands.compile import compile_in_background, optimiser_cached; " \
            "c = compile_in_background(); assert c is not None and c.wait(600) == 0; print(optimiser_cached())"
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "True"
    again = "from vmesh.commands.compile import _claim_background_compile as c; print(c())"  # the lock is taken
    assert subprocess.run([sys.executable, "-c", again], env=env, capture_output=True, text=True, check=True).stdout.split()[-1] == "False"


def test_openmp_threads_sleep_unless_the_user_chose():
    """Importing vmesh makes libgomp's idle threads passive (spinning after each of the
    builder's thousands of short parallel regions doubled its CPU), but keeps a policy
    the user set."""
    code = "import os, vmesh; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "PASSIVE"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_WAIT_POLICY": "ACTIVE"}, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ACTIVE"
