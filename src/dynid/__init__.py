"""dynid: experimental identification of the dynamic parameters of robot manipulators.

``import dynid`` stays light: submodules (``dynid.model``, ``dynid.estimation``, ...) are
imported on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_SUBMODULES = ("dataset", "errors", "signals", "stats", "model", "estimation", "io", "report", "config", "pipeline")


_FUNCTIONS = {"identify_arrays": "dynid.pipeline.arrays"}  # imported on first use, like the submodules


def __getattr__(name: str) -> Any:
    if name in _SUBMODULES:
        return importlib.import_module(f"dynid.{name}")
    if name in _FUNCTIONS:
        return getattr(importlib.import_module(_FUNCTIONS[name]), name)
    raise AttributeError(f"module 'dynid' has no attribute {name!r}")
