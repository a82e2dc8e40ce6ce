"""vmesh: block-structured hexahedral meshes of blood vessels.

Every stage is a registered filter (:func:`filter_list`,
:func:`print_filter_parameter_list`) and a :class:`FilterChain` runs them in order::

    import vmesh
    chain = vmesh.FilterChain.load("default")
    ctx = chain.run(surface="vessel.stl", out_dir="out")
"""

__version__ = "0.1.0"

import os as _os  # noqa: E402

# numba's parallel kernels run on OpenMP (libgomp), whose idle threads by default spin for a
# while after every parallel region. vmesh launches thousands of short regions (the block
# builder's trial fills, the optimiser's colours): the spinning doubled the CPU of the
# builder and took the second core from the main thread and from pymeshlab. Passive
# threads sleep at once (a wake-up costs microseconds); read when libgomp loads, and only
# where the user has not chosen a policy.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from .numba_cache import install as _install_numba_cache  # noqa: E402

_install_numba_cache()  # before any kernel is decorated: kernels cached by source content, not path

from .chain import FilterChain, Step, list_presets  # noqa: E402
from .context import Context, Report  # noqa: E402
from .errors import ChainError, InputError, MeshingError, ParameterError, VmeshError  # noqa: E402
from .io.skeleton import read_skeleton, write_skeleton  # noqa: E402
from .io.surface import read_surface, write_surface  # noqa: E402
from .registry import (  # noqa: E402
    Parameter,
    filter_list,
    get_filter,
    print_filter_list,
    print_filter_parameter_list,
    register_filter,
)
from .skeleton import Skeleton  # noqa: E402
from .surface import SurfaceMesh  # noqa: E402

__all__ = [
    "FilterChain",
    "Step",
    "Context",
    "Report",
    "Parameter",
    "register_filter",
    "get_filter",
    "filter_list",
    "print_filter_list",
    "print_filter_parameter_list",
    "list_presets",
    "read_surface",
    "write_surface",
    "read_skeleton",
    "write_skeleton",
    "SurfaceMesh",
    "Skeleton",
    "VmeshError",
    "InputError",
    "ParameterError",
    "ChainError",
    "MeshingError",
    "SignedDistance",
    "TwoStepSignedDistance",
    "OctreeSignedDistance",
]


def __getattr__(name):
    # the signed distance pulls in numba: imported on first use, not with vmesh
    if name in ("SignedDistance", "TwoStepSignedDistance"):
        from .geometry import sdf

        return getattr(sdf, name)
    if name == "OctreeSignedDistance":
        from .geometry.octree_sdf import OctreeSignedDistance

        return OctreeSignedDistance
    raise AttributeError(f"module 'vmesh' has no attribute {name!r}")

from . import batch  # noqa: E402,F401  (vmesh.batch.run; dask is imported only when a batch runs)
