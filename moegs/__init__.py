"""moegs: Mixture-of-Experts dynamic Gaussian Splatting, reproducible.

Nothing heavy is imported here: ``Camera``, ``GaussianFrame`` and ``cat`` load torch on first access, so
``moegs list`` and the expert registry stay instant.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"Camera": "moegs.camera", "GaussianFrame": "moegs.gaussians", "cat": "moegs.gaussians"}

__all__ = ["Camera", "GaussianFrame", "cat"]
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'moegs' has no attribute {name!r}")
