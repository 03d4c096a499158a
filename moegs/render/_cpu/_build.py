"""Compiler flags shared by ``setup.py`` and the developer build (``python -m moegs.render._cpu build``).

No ``-march=native`` (the wheel must run on any CPU of the architecture) and no ``-ffast-math``:
the kernel must reproduce the float32 operation order of the torch reference, so FMA contraction is
switched off too.
"""

from __future__ import annotations

COMPILE_ARGS = ["-O3", "-std=c99", "-fPIC", "-fopenmp", "-ffp-contract=off", "-fvisibility=hidden"]
LINK_ARGS = ["-fopenmp"]
# Fallback when the compiler has no OpenMP (e.g. Apple clang without libomp): serial but correct.
COMPILE_ARGS_NO_OPENMP = [a for a in COMPILE_ARGS if a != "-fopenmp"]
LINK_ARGS_NO_OPENMP: list[str] = []
