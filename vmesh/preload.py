"""Import the modules a chain's later steps will need while a step waits on another thread.

The filters import their geometry modules inside the filter functions (a chain that never
meshes does not pay for the mesher's imports), so a run imports the block builder, the
transfinite mesher, the optimiser and their numba kernels (whose cache locators digest their
sources) step by step, ~0.3-0.4 s CPU on the critical path of the ICA at vascularmd's
resolution (docs/speed.md, 20th round). ``decimate_surface`` waits ~2 s for pymeshlab, which
runs in a thread without the GIL: the main thread imports the later steps' modules meanwhile
(:func:`import_later_steps`), so they cost no wall time on a machine with an idle core.

The chain runner says which steps come after the running one (:data:`LATER_STEPS`, a context
variable set around each step by :meth:`vmesh.chain.FilterChain.run`); a step's modules are
the vmesh modules imported inside its filter function and inside the functions of the same
module it calls by name (:func:`lazy_imports`). Importing a module earlier changes no result.
A waiting step may also build what later steps will ask of the surface it holds
(:func:`prepare_surface`: the fine surface's signed distance for a two-step ``build_sdf``,
:func:`vmesh.geometry.projection.surface_distance`; ``check_coverage``'s
:class:`~vmesh.geometry.coverage.SurfaceFacts`), computed by the same functions either way
and cached per surface object, where the later step finds them.
"""

from __future__ import annotations

import ast
import contextvars
import functools
import importlib
import inspect
import sys

from .source_imports import imported_names

#: The steps (:class:`vmesh.chain.Step`, parameters resolved) the running chain will run after
#: the current one (empty outside a chain).
LATER_STEPS: contextvars.ContextVar[tuple] = contextvars.ContextVar("vmesh_later_steps", default=())


@functools.lru_cache(maxsize=None)
def _module_functions(module_name: str) -> dict[str, ast.AST]:
    """The top-level functions of a module, by name, from its source."""
    tree = ast.parse(inspect.getsource(sys.modules[module_name]))
    return {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}


@functools.lru_cache(maxsize=None)
def lazy_imports(module_name: str, function_name: str) -> tuple[str, ...]:
    """The vmesh modules imported inside function ``function_name`` of module
    ``module_name`` and inside the functions of that module it calls by name, transitively
    (in order of appearance, without repeats)."""
    functions = _module_functions(module_name)
    package = module_name.rpartition(".")[0]
    found: dict[str, None] = {}
    seen, todo = {function_name}, [function_name]
    while todo:
        node = functions.get(todo.pop(0))
        if node is None:
            continue
        for child in ast.walk(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.update(dict.fromkeys(imported_names(child, package)))
            elif isinstance(child, ast.Name) and child.id in functions and child.id not in seen:
                seen.add(child.id)
                todo.append(child.id)
    return tuple(found)


def import_later_steps() -> list[str]:
    """Import the modules of :data:`LATER_STEPS` not imported yet; returns their names.

    A module that fails to import is left to its step, which reports the error where it
    belongs; a name that is not a module (``from .. import some_function``) is skipped."""
    from .registry import get_filter

    done = []
    for name in dict.fromkeys(step.filter for step in LATER_STEPS.get()):
        try:
            function = get_filter(name).function
            modules = lazy_imports(function.__module__, function.__name__)
        except Exception:  # no source (a frozen build) or an unknown filter: nothing to preload
            continue
        for module in modules:
            if module in sys.modules:
                continue
            try:
                importlib.import_module(module)
            except Exception:  # the step itself raises it, with its step number
                continue
            done.append(module)
    return done


def prepare_surface(surface) -> list[str]:
    """Build what the later steps (:data:`LATER_STEPS`) will ask of ``surface``, if it is still
    the chain's surface then: a two-step ``build_sdf``'s fine signed distance and
    ``check_coverage``'s surface facts (:meth:`~vmesh.geometry.coverage.SurfaceFacts.compute`).
    Returns what was built. An error is left to the step that needs the result: it raises it there."""
    from .geometry.coverage import surface_facts
    from .geometry.projection import surface_distance

    done = []
    for step in LATER_STEPS.get():
        p = step.params
        try:
            if step.filter == "build_sdf" and p.get("refine_on_fine") and p.get("source") == "coarse":
                surface_distance(surface, sign=p.get("sign", "auto"))
                done.append("signed distance")
            elif step.filter == "check_coverage":
                surface_facts(surface).compute()
                done.append("coverage facts")
        except Exception:  # the step itself raises it, with its step number
            continue
    return done
