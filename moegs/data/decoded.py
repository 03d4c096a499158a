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
full-resolution video frames would fill the disk). Each entry stores the SHA-256 of its arrays, checked
when read: a damaged or edited entry is decoded again and overwritten, never used. ``MOEGS_DECODED_CACHE=0``
turns it off.
"""

from __future__ import annotations

import hashlib
import os
import zipfile
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


def _digest(*arrays: np.ndarray) -> str:
    """SHA-256 of ``arrays`` (dtype, shape and bytes of each)."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _entry(kind: str, sources: Sequence[Path], args: tuple, suffix: str = ".npz") -> Path:
    stats = [(str(s.resolve()), s.stat().st_size, s.stat().st_mtime_ns) for s in sources]
    digest = hashlib.sha256(repr((kind, stats, args)).encode()).hexdigest()
    return cache_root() / "decoded" / digest[:2] / f"{digest}{suffix}"


def _load(path: Path, names: tuple[str, ...]) -> list[np.ndarray] | None:
    """The arrays ``names`` of the entry at ``path`` when its stored digest matches them, else None
    (missing, truncated, damaged or edited: decode again and overwrite)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays, digest = [z[n] for n in names], str(z["sha256"])
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
        return None
    return arrays if digest == _digest(*arrays) else None


def _read(path: Path, shape: tuple[int, ...], dtype: torch.dtype) -> Tensor | None:
    arrays = _load(path, ("value",))
    if arrays is None:
        return None
    value = torch.from_numpy(arrays[0])
    return value if value.shape == shape and value.dtype == dtype else None


def _save_arrays(file: BinaryIO, **arrays: np.ndarray) -> None:
    """``arrays`` and their digest (``sha256``) into one ``.npz``."""
    np.savez(file, **arrays, sha256=np.array(_digest(*arrays.values())))


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
            _write(entry, partial(_save_arrays, value=value.contiguous().numpy()))
    return value


def cached_points(sources: Sequence[Path], args: tuple, load: Callable[[], PointCloud]) -> PointCloud:
    """``load()`` (points computed from the files ``sources`` with parameters ``args``), read from the disk
    cache when an entry exists, else computed and stored. Exceptions of ``load`` propagate uncached."""
    if not enabled():
        return load()
    try:
        entry = _entry("points", sources, args)
    except OSError:
        return load()
    arrays = _load(entry, ("xyz", "rgb", "source"))
    if arrays is not None:
        xyz, rgb, source = arrays
        return PointCloud(torch.from_numpy(xyz), torch.from_numpy(rgb), str(source))
    points = load()
    if points.times is None:
        values = {"xyz": points.xyz.numpy(), "rgb": points.rgb.numpy(), "source": np.array(points.source)}
        _write(entry, partial(_save_arrays, **values))
    return points
