"""Built-in filters. Importing this package registers them all.

Each module is a thin wrapper around the kernels of one stage.
"""

from . import io_filters  # noqa: F401
from . import preprocess_filters, meshlab_filters  # noqa: F401
from . import skeleton_filters  # noqa: F401
from . import block_filters  # noqa: F401
from . import extract_filters  # noqa: F401
from . import mesh_filters  # noqa: F401
from . import export_filters  # noqa: F401
from . import variation_filters  # noqa: F401
