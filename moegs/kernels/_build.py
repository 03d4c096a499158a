"""How the compiled CPU library is built: shared by ``setup.py`` and ``python -m moegs.kernels build``.

No ``-march=native`` (the wheel must run on any CPU of the architecture: the compositing builds an
AVX2 clone of its hot loops and picks it at load time) and no ``-ffast-math``: the kernels must
reproduce the float32 operation order of their torch references, so FMA contraction is switched off
too. Loaded by path from ``setup.py``, so it imports nothing from moegs.
"""

from __future__ import annotations

LIBRARY = "_cpu"
"""File stem of the library, built next to ``moegs/kernels/__init__.py``."""
SOURCES = ("raster.c", "project.c", "hashgrid.c")
"""C files of the library, in ``moegs/kernels/``."""
HEADERS = ("moegs_api.h",)
"""Header they share (export attribute, OpenMP), in ``moegs/kernels/``."""
# -Wno-psabi: GCC notes an ABI change for passing vector types (raster.c's static inline ``narrow``)
COMPILE_ARGS = [
    "-O3",
    "-std=c99",
    "-fPIC",
    "-fopenmp",
    "-ffp-contract=off",
    "-fvisibility=hidden",
    "-Wno-psabi",
]
LINK_ARGS = ["-fopenmp"]
# Fallback when the compiler has no OpenMP (e.g. Apple clang without libomp): serial but correct.
COMPILE_ARGS_NO_OPENMP = [a for a in COMPILE_ARGS if a != "-fopenmp"]
LINK_ARGS_NO_OPENMP: list[str] = []
