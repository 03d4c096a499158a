"""Atomic file writes: a file is replaced whole or not at all.

``atomic_path`` hands the block a temporary file beside the target and moves it onto the target in one
step (``os.replace``) when the block ends; if the block raises, the temporary is removed. So an
interrupted write never leaves a half-written target or a stray temporary, and a process that still has
the old file open (or mapped, like a loaded kernel library) keeps reading the old contents.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def umask_mode(executable: bool = False) -> int:
    """Permission bits a new file gets under the process umask (0666, or 0777 for an ``executable``,
    less the umask; ``mkstemp`` itself gives 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return (0o777 if executable else 0o666) & ~mask


@contextmanager
def atomic_path(path: str | Path, executable: bool = False) -> Iterator[Path]:
    """A new empty temporary file beside ``path`` (``.<name>.<random>.tmp``) for the block to write or
    overwrite; it takes the umask's permissions (``umask_mode``) and replaces ``path`` when the block
    ends, and is removed when the block raises. Creates ``path``'s folder if needed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, umask_mode(executable))  # writers that make their own file (safetensors) give 0600
        os.replace(tmp, path)
    except OSError as err:
        if err.errno in (errno.ENOSPC, errno.EDQUOT):  # writers often name no file: name it and the space
            free = shutil.disk_usage(path.parent).free
            full = OSError(
                f"cannot write {path}: no space left on its disk ({free / 2**20:.1f} MiB free); "
                "free some space and run the command again (finished files are kept)"
            )
            full.errno = err.errno
            raise full from None
        raise
    finally:
        tmp.unlink(missing_ok=True)
