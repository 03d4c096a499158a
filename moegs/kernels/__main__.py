"""Developer build: ``python -m moegs.kernels build [--cc CC]``.

Compiles the C files in place with the system C compiler and the same flags as ``setup.py``, for
people editing them (a rebuild takes a few seconds). ``python -m moegs.kernels`` without arguments
prints whether the library is available.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import sysconfig
from pathlib import Path

import moegs.kernels as kernels
from moegs.atomic import atomic_path
from moegs.kernels import _build

HERE = Path(__file__).resolve().parent


def build(cc: str | None = None, verbose: bool = True) -> Path:
    """Compile ``_build.SOURCES`` into ``_cpu<EXT_SUFFIX>`` next to them and return the library path."""
    cc = cc or os.environ.get("CC", "cc")
    target = HERE / f"{_build.LIBRARY}{sysconfig.get_config_var('EXT_SUFFIX')}"
    sources = [str(HERE / name) for name in _build.SOURCES]
    # written atomically: a process that has the old library mapped keeps it
    with atomic_path(target, executable=True) as tmp:
        cmd = [*shlex.split(cc), *_build.COMPILE_ARGS, "-shared", *sources, "-o", str(tmp), *_build.LINK_ARGS]
        if verbose:
            print(" ".join(cmd))
        subprocess.run(cmd, check=True)
    kernels.reset()
    if verbose:
        print(f"built {target}")
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m moegs.kernels", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd")
    b = sub.add_parser("build", help="compile the C files in place with the system C compiler")
    b.add_argument("--cc", default=None, help="C compiler command (default: $CC or cc)")
    args = parser.parse_args(argv)
    if args.cmd == "build":
        try:
            build(args.cc)
        except (OSError, subprocess.CalledProcessError) as exc:
            print(f"build failed: {exc}", file=sys.stderr)
            return 1
        return 0
    if kernels.is_available():
        print(f"moegs CPU kernels available: {kernels.library_path()}")
        return 0
    print(f"moegs CPU kernels unavailable: {kernels.load_error()}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
