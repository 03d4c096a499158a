"""Decoded ground truth kept on disk between processes.

Every training run of a scene decodes, composites and resizes the same images again (a D-NeRF view at
800x800 -> 100x100: about 28 ms, some 4 s per quick run of ``mutant``, up to a third of it). The first
run stores each result under ``cache_root()/decoded/`` and later runs read it back (well under a
millisecond). It is exact: the stored array (uint8 images, float32 masks) is the loader's own result,
written atomically.

Entries are keyed by the source files' resolved paths, sizes and modification times and by every
loading argument. Initial point clouds computed from images (``cached_points``: Panoptic's
triangulation, 7-10 s per load of basketball) are kept the same way. Only images of at most
``MAX_PIXELS`` pixels are stored (training resolutions of the quick and standard presets;
full-resolution video frames would fill the disk). ``MOEGS_DECODED_CACHE=0`` turns it
off.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import BinaryIO

import numpy as np
import torch
from torch import Tensor

from moegs.atomic import atomic_path
from moegs.data.scene import PointCloud
from moegs.paths import cache_root

MAX_PIXELS = 512 * 512


def enabled() -> bool:
    return os.environ.get("MOEGS_DECODED_CACHE", "1") != "0"


def _entry(kind: str, sources: Sequence[Path], args: tuple, suffix: str = ".npy") -> Path:
    stats = [(str(s.resolve()), s.stat().st_size, s.stat().st_mtime_ns) for s in sources]
    digest = hashlib.sha256(repr((kind, stats, args)).encode()).hexdigest()
    return cache_root() / "decoded" / digest[:2] / f"{digest}{suffix}"


def _read(path: Path, shape: tuple[int, ...], dtype: torch.dtype) -> Tensor | None:
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None  # missing, truncated or damaged: decode again and overwrite
    value = torch.from_numpy(arr)
    return value if value.shape == shape and value.dtype == dtype else None


def _write(path: Path, save: Callable[[BinaryIO], None]) -> None:
    """Atomically write ``path`` with ``save(file)``; a cache that cannot be written is skipped."""
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            save(f)
    except OSError:
        pass  # a read-only or full cache only costs the speed-up


def cached(
    kind: str,
    source: Path,
    args: tuple,
    shape: tuple[int, ...],
    load: Callable[[], Tensor],
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """``load()`` (a tensor of ``shape`` and ``dtype`` decoded from ``source``), read from the disk cache
    when an entry for ``(kind, source, args)`` exists, else computed and stored."""
    if not enabled() or shape[0] * shape[1] > MAX_PIXELS:
        return load()
    try:
        entry = _entry(kind, [source], args)
    except OSError:
        return load()  # a missing source: the loader's own message names it
    value = _read(entry, shape, dtype)
    if value is None:
        value = load()
        if value.dtype == dtype and tuple(value.shape) == shape:
            _write(entry, partial(np.save, arr=value.contiguous().numpy()))
    return value


def cached_points(sources: Sequence[Path], args: tuple, load: Callable[[], PointCloud]) -> PointCloud:
    """``load()`` (points computed from the files ``sources`` with parameters ``args``), read from the disk
    cache when an entry exists, else computed and stored. Exceptions of ``load`` propagate uncached."""
    if not enabled():
        return load()
    try:
        entry = _entry("points", sources, args, ".npz")
    except OSError:
        return load()
    try:
        with np.load(entry, allow_pickle=False) as z:
            xyz, rgb, source = z["xyz"], z["rgb"], str(z["source"])
        return PointCloud(torch.from_numpy(xyz), torch.from_numpy(rgb), source)
    except (OSError, ValueError, EOFError, KeyError):
        pass  # missing or damaged: compute again and overwrite
    points = load()
    if points.times is None:
        arrays = {"xyz": points.xyz.numpy(), "rgb": points.rgb.numpy(), "source": np.array(points.source)}
        _write(entry, lambda f: np.savez(f, **arrays))
    return points
