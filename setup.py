"""Build of the compiled CPU library (all other metadata lives in pyproject.toml).

``moegs/kernels/*.c`` (compositing, projection and hash encoding) are C99 + OpenMP with GCC/clang
vector extensions and no Python or torch headers; the library is loaded with ctypes, never imported.
It is declared as a setuptools ``Extension`` only because that is the portable way to get a compiled
shared library built and installed by ``pip install .`` and ``pip install -e .`` (build_ext handles
the compiler, in-place editable builds and wheel tagging). ``raster.c`` exports a stub
``PyInit__cpu`` so linkers that expect one are satisfied.

The extension is ``optional``: without a C compiler that has the vector extensions (GCC or clang;
not MSVC) the install still succeeds and moegs falls back to its pure-torch references
(``moegs.kernels.is_available()`` is then False). No torch is needed at build time.
"""

from __future__ import annotations

import os
import runpy
import tempfile

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# flags and sources shared with `python -m moegs.kernels build`; loaded by path so that building never
# imports the moegs package (which needs torch)
_HERE = os.path.dirname(os.path.abspath(__file__))
_flags = runpy.run_path(os.path.join(_HERE, "moegs", "kernels", "_build.py"))


def _has_openmp(compiler) -> bool:
    """Whether the C compiler accepts -fopenmp (probe: compile and link a tiny program)."""
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "omp_probe.c")
        with open(src, "w") as f:
            f.write("#include <omp.h>\nint main(void) { return omp_get_max_threads() > 0 ? 0 : 1; }\n")
        try:
            objs = compiler.compile([src], output_dir=tmp, extra_postargs=["-fopenmp"])
            compiler.link_executable(objs, os.path.join(tmp, "omp_probe"), extra_postargs=["-fopenmp"])
        except Exception:  # noqa: BLE001 - any failure means "no OpenMP"
            return False
    return True


class BuildExt(build_ext):
    def build_extensions(self):
        if _has_openmp(self.compiler):
            compile_args, link_args = _flags["COMPILE_ARGS"], _flags["LINK_ARGS"]
        else:
            print("moegs: C compiler has no OpenMP; building the CPU kernels single-threaded")
            compile_args, link_args = _flags["COMPILE_ARGS_NO_OPENMP"], _flags["LINK_ARGS_NO_OPENMP"]
        for ext in self.extensions:
            ext.extra_compile_args = list(compile_args)
            ext.extra_link_args = list(link_args)
        super().build_extensions()


setup(
    ext_modules=[
        Extension(
            f"moegs.kernels.{_flags['LIBRARY']}",
            sources=[f"moegs/kernels/{name}" for name in _flags["SOURCES"]],
            depends=[f"moegs/kernels/{name}" for name in _flags["HEADERS"]],
            optional=True,
        )
    ],
    cmdclass={"build_ext": BuildExt},
)
