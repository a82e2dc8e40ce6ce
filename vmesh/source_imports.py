"""Which vmesh modules an import statement loads, read from the source (no import runs).

Two readers need it: the numba cache keys a kernel module's cache on the sources of the kernel
modules it imports (:mod:`vmesh.numba_cache`), and the chain imports its later steps' modules
while pymeshlab decimates (:mod:`vmesh.preload`).
"""

from __future__ import annotations

import ast
import importlib.util


def imported_names(node: ast.Import | ast.ImportFrom, package: str) -> list[str]:
    """The dotted names of the vmesh modules import statement ``node`` may load.

    Parameters
    ----------
    node : ast.Import or ast.ImportFrom
        The statement.
    package : str
        The package the statement's module sits in (``vmesh.geometry`` for
        ``vmesh/geometry/sdf.py`` and for ``vmesh/geometry/__init__.py``), for relative imports.

    Returns
    -------
    list of str
        For ``import vmesh.a``: ``vmesh.a``. For ``from X import n1, n2``: ``X`` and ``X.n1``,
        ``X.n2`` (the names may be submodules: ``from .. import disk_cache``); names that are not
        modules are the caller's to drop. Other packages' imports give nothing.
    """
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "vmesh"]
    if node.level:
        base = importlib.util.resolve_name("." * node.level + (node.module or ""), package)
    elif (node.module or "").split(".")[0] == "vmesh":
        base = node.module
    else:
        return []
    return [base] + [f"{base}.{a.name}" for a in node.names]
