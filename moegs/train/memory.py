"""Let the process keep freed heap memory instead of handing it back to the OS (glibc only).

Training allocates and frees the same large tensors at every step (renders, per-tile buffers,
gradients). By default glibc serves blocks above a moving threshold with fresh ``mmap`` pages and
trims the top of the heap after frees, so every step pays page faults to zero new pages: measured
on the 2-core CPU machine, 23 s of E-D3DGS's 94 s quick training on the stand-in N3V scene was
kernel time. Fixed mmap and trim thresholds let malloc reuse those blocks (what PyTorch's caching
allocator does on CUDA); the same training then took 80 s, with under 1 s in the kernel.

The setting is process-wide and keeps the resident set near the process's peak. Set
``MOEGS_KEEP_FREED_MEMORY=0`` to leave malloc alone.
"""

from __future__ import annotations

import ctypes
import os
import sys
from functools import cache

ENV = "MOEGS_KEEP_FREED_MEMORY"
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3  # glibc <malloc.h>
SETTINGS = {
    _M_MMAP_THRESHOLD: 32 << 20,  # the largest value every 64-bit glibc accepts
    _M_TRIM_THRESHOLD: 1 << 30,
    _M_TOP_PAD: 64 << 20,
}


@cache
def keep_freed_memory() -> bool:
    """Apply :data:`SETTINGS` once per process; True when glibc accepted all of them."""
    if os.environ.get(ENV, "1") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return all([mallopt(param, value) == 1 for param, value in SETTINGS.items()])  # a list: apply every one
