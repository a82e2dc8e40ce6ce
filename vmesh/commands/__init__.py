"""Extra sub-commands of the ``vmesh`` command line.

Each module registers itself in :data:`vmesh.cli.EXTRA_COMMANDS` as
``name -> (add_arguments(parser), run(args) -> int, help)``.
"""

import importlib

for _name in ("skeleton", "export", "render", "batch", "compile"):  # modules are appended here as stages add commands
    importlib.import_module(f"{__name__}.{_name}")
