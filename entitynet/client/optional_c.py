"""One rule for loading the client's optional compiled twins.

Why: each compiled module of the client (`_cover`, `_occupy`, `_payload`, `_ghost_queue`, `_lateral`,
`_waytable`) is optional: pip builds it where a C compiler is found, and its pure reference runs otherwise, or
wherever ENTITYNET_PURE_PYTHON is set (how the tests and the benchmarks run the references). That rule was
written out in each module, in slightly different shapes; here it is once.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType


def compiled(name: str) -> ModuleType | None:
    """The compiled module `entitynet.client.<name>`, or None where it was not built or ENTITYNET_PURE_PYTHON
    asks for the pure references."""
    if os.environ.get("ENTITYNET_PURE_PYTHON"):
        return None
    try:
        return importlib.import_module(f"entitynet.client.{name}")
    except ImportError:
        return None
