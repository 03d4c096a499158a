"""The compiled CPU library (C + OpenMP, loaded with ctypes): compositing, projection and hash encoding.

One shared library, ``_cpu<EXT_SUFFIX>`` next to this file, built from ``raster.c`` (front-to-back
compositing) and ``project.c`` (EWA projection), both used by :mod:`moegs.render._cpu`, and
``hashgrid.c`` (multiresolution hash encoding, used by :mod:`moegs.fields.hashgrid`) by the package
build (``setup.py``) or, for people editing the C files, by ``python -m moegs.kernels build``. The C
code has no torch or Python headers: callers allocate every buffer as a torch tensor and pass raw
pointers. Each kernel has a pure-torch reference beside it that it is tested against.

If the library is missing or stale, :func:`library` is None, :func:`load_error` says why, and callers
use their torch references. Set ``MOEGS_DISABLE_CPU_KERNEL=1`` to force that fallback.
"""

from __future__ import annotations

import ctypes
import importlib.machinery
import os
from pathlib import Path

from moegs.kernels import _build

__all__ = ["check", "is_available", "library", "library_path", "load_error"]

ABI_VERSION = 3  # must match MOEGS_ABI_VERSION in raster.c
DISABLE_ENV = "MOEGS_DISABLE_CPU_KERNEL"
_HERE = Path(__file__).resolve().parent
_ERRORS = {-1: "out of memory", -2: "groups out of range [0, num_groups)", -3: "invalid arguments"}

_lib: ctypes.CDLL | None = None
_error: str | None = None
_loaded = False


def library_path() -> Path | None:
    """The compiled library next to this file (first match in EXTENSION_SUFFIXES order), or None."""
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = _HERE / f"{_build.LIBRARY}{suffix}"
        if path.is_file():
            return path
    return None


def _declare(lib: ctypes.CDLL) -> None:
    p, i32, i64 = ctypes.c_void_p, ctypes.c_int32, ctypes.c_int64
    lib.moegs_abi_version.restype = ctypes.c_int
    lib.moegs_abi_version.argtypes = []
    lib.moegs_prepare.restype = i64
    lib.moegs_prepare.argtypes = [i64, i64, i32, i32, i32, i32, i32] + [p] * 13
    lib.moegs_forward.restype = ctypes.c_int
    lib.moegs_forward.argtypes = [i64, i64, i32, i32, i32, i32, i32] + [p] * 7 + [i64] + [p] * 7
    lib.moegs_backward.restype = ctypes.c_int
    lib.moegs_backward.argtypes = [i64, i64, i32, i32, i32, i32, i32] + [p] * 7 + [i64] + [p] * 10
    f32 = ctypes.c_float
    lib.moegs_project_forward.restype = ctypes.c_int
    lib.moegs_project_forward.argtypes = [i64, i32] + [p] * 4 + [i32, i32, f32, f32, i32] + [p] * 5
    lib.moegs_project_backward.restype = ctypes.c_int
    lib.moegs_project_backward.argtypes = [i64, i32] + [p] * 4 + [f32, f32, i32] + [p] * 7
    lib.moegs_covariance_forward.restype = ctypes.c_int
    lib.moegs_covariance_forward.argtypes = [i64, i32] + [p] * 3
    lib.moegs_covariance_backward.restype = ctypes.c_int
    lib.moegs_covariance_backward.argtypes = [i64, i32] + [p] * 5
    for name in ("moegs_hashgrid_forward", "moegs_hashgrid_backward"):
        fn = getattr(lib, name)
        fn.restype = ctypes.c_int
        fn.argtypes = [i64, i32, i32, i32, i32] + [p] * 8


def library() -> ctypes.CDLL | None:
    """The loaded library, or None when it is unavailable (see :func:`load_error`)."""
    global _lib, _error, _loaded
    if _loaded:
        return _lib
    _loaded = True
    if os.environ.get(DISABLE_ENV, "") not in ("", "0"):
        _error = f"disabled by {DISABLE_ENV}"
        return None
    path = library_path()
    if path is None:
        _error = (
            f"compiled library {_build.LIBRARY}<{importlib.machinery.EXTENSION_SUFFIXES[0]}> not found in "
            f"{_HERE}; reinstall the package (`pip install -e .`) or run `python -m moegs.kernels build`"
        )
        return None
    try:
        lib = ctypes.CDLL(str(path))
        _declare(lib)
        version = lib.moegs_abi_version()
    except (OSError, AttributeError) as exc:
        _error = f"cannot load {path}: {exc}"
        return None
    if version != ABI_VERSION:
        _error = (
            f"{path} has ABI version {version}, expected {ABI_VERSION} (stale build); "
            "rebuild with `python -m moegs.kernels build` or `pip install -e .`"
        )
        return None
    _lib = lib
    return lib


def is_available() -> bool:
    """True if the compiled library is built, loadable and of the expected ABI version."""
    return library() is not None


def load_error() -> str | None:
    """Why the library is unavailable (None when it is available)."""
    library()
    return _error


def reset() -> None:
    """Forget the loaded library (the dev build and tests use it; an old library stays mapped)."""
    global _lib, _error, _loaded
    _lib, _error, _loaded = None, None, False


def check(code: int, what: str) -> None:
    """Raise for a negative return code of a kernel: ``MemoryError`` (-1) or ``ValueError``."""
    if code < 0:
        msg = _ERRORS.get(int(code), f"error {code}")
        if code == -1:
            raise MemoryError(f"moegs CPU kernel ({what}): {msg}")
        raise ValueError(f"moegs CPU kernel ({what}): {msg}")
