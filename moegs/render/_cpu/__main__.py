"""Developer build: ``python -m moegs.render._cpu build [--cc CC]``.

Compiles ``raster.c`` in place with the system C compiler and the same flags as ``setup.py``, for
people editing the C file (a rebuild takes well under a second). ``python -m moegs.render._cpu``
without arguments prints whether the kernel is available.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from moegs.render._cpu import _build

HERE = Path(__file__).resolve().parent


def build(cc: str | None = None, verbose: bool = True) -> Path:
    """Compile ``raster.c`` into ``_raster<EXT_SUFFIX>`` next to it and return the library path."""
    cc = cc or os.environ.get("CC", "cc")
    target = HERE / f"_raster{sysconfig.get_config_var('EXT_SUFFIX')}"
    src = HERE / "raster.c"
    # write to a temporary name then rename: a process that has the old library mapped keeps it
    fd, tmp = tempfile.mkstemp(prefix="._raster", suffix=".so", dir=HERE)
    os.close(fd)
    cmd = [*shlex.split(cc), *_build.COMPILE_ARGS, "-shared", str(src), "-o", tmp, *_build.LINK_ARGS]
    if verbose:
        print(" ".join(cmd))
    try:
        subprocess.run(cmd, check=True)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    if verbose:
        print(f"built {target}")
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m moegs.render._cpu", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd")
    b = sub.add_parser("build", help="compile raster.c in place with the system C compiler")
    b.add_argument("--cc", default=None, help="C compiler command (default: $CC or cc)")
    args = parser.parse_args(argv)
    if args.cmd == "build":
        try:
            build(args.cc)
        except (OSError, subprocess.CalledProcessError) as exc:
            print(f"build failed: {exc}", file=sys.stderr)
            return 1
        return 0
    from moegs.render import _cpu

    if _cpu.is_available():
        print(f"moegs CPU kernel available: {_cpu.library_path()}")
        return 0
    print(f"moegs CPU kernel unavailable: {_cpu.load_error()}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
