"""Checks of the commands before they train: image sizes the metrics can score, and one writer per run
folder.

* ``check_image_sizes``: every view at least ``min_image_size()`` pixels a side (LPIPS-Alex needs 31: its
  second max-pool needs an input of 3, ``moegs.metrics.lpips.MIN_SIZE``; SSIM's window is 11), else one
  line naming the resolution-scale argument, the size and the smallest scale that works.
* ``folder_lock``: an advisory ``flock`` on the run folder itself (no lock file, so nothing in the folder
  changes and finished-run detection and resume are untouched); a second command on the folder gets one
  line. The kernel drops the lock when the process ends, however it ends.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def min_image_size() -> int:
    """Smallest side, in pixels, that SSIM (its window) and LPIPS-Alex (its network) can score."""
    from moegs.metrics.lpips import MIN_SIZE
    from moegs.metrics.ssim import WINDOW

    return max(MIN_SIZE, WINDOW)


def _sizes_note() -> str:
    from moegs.metrics.lpips import MIN_SIZE
    from moegs.metrics.ssim import WINDOW

    need = min_image_size()
    return f"SSIM and LPIPS need at least {need}x{need} (SSIM's window: {WINDOW} px, LPIPS-Alex: {MIN_SIZE})"


def smallest_scale(side: int, scale: float, native: int | None = None) -> float:
    """The smallest scale (3 decimals, rounded up) at which a side of ``side`` pixels at ``scale`` (native
    ``native`` pixels when known) reaches ``min_image_size()`` however a loader rounds the size."""
    full = native or side / scale
    return math.ceil(1000 * min_image_size() / full) / 1000


def check_image_sizes(scene, scale: float | None, flag: str = "--resolution-scale ") -> None:
    """Refuse ``scene`` when a view is smaller than ``min_image_size()``: ``ValueError`` naming ``flag`` (the
    argument that sets the scale, with its separator: ``"--set train.resolution_scale="``), the scale
    (``scale``, else the loader's ``meta["resolution_scale"]``), the size and the smallest scale that
    works."""
    views = [*scene.train, *scene.test]
    if not views:
        return
    view = min(views, key=lambda v: min(v.camera.width, v.camera.height))
    width, height = view.camera.width, view.camera.height
    if min(width, height) >= min_image_size():
        return
    scale = scale if scale is not None else scene.meta.get("resolution_scale")
    if not isinstance(scale, int | float) or scale <= 0:
        raise ValueError(f"{scene.name}'s images are {width}x{height} pixels ({view.key}); {_sizes_note()}")
    native = scene.meta.get("native_size")
    lowest = smallest_scale(min(width, height), scale, min(native) if native else None)
    fix = f"use {flag}{lowest:g} or more" if lowest <= 1 else "they are smaller even at full resolution"
    raise ValueError(
        f"{flag}{scale:g} makes {scene.name}'s images {width}x{height} pixels ({view.key}); "
        f"{_sizes_note()}: {fix}"
    )


def load_checked(load: Callable[[], Any], scale: float | None, flag: str = "--resolution-scale "):
    """``load()`` (a scene), then ``check_image_sizes``; a scale that rounds a camera to 0 pixels (the
    camera refuses it while loading) is named the same way."""
    try:
        scene = load()
    except ValueError as err:
        if scale is None or not str(err).startswith("Camera size must be positive"):
            raise
        size = str(err).rsplit(" ", 1)[-1]
        raise ValueError(
            f"{flag}{scale:g} makes the images {size} pixels; {_sizes_note()}: use a larger scale"
        ) from err
    check_image_sizes(scene, scale, flag)
    return scene


class FolderInUse(OSError):
    """Another process holds the lock of a run folder."""


@contextmanager
def folder_lock(folder: str | Path, flag: str = "--out") -> Iterator[Path]:
    """Hold an exclusive ``flock`` on ``folder`` (made if missing, removed on exit if still empty) while the
    block runs; ``FolderInUse`` naming the folder and ``flag`` when another process holds it."""
    folder = Path(folder)
    made = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            import fcntl

            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:  # no flock on this system: no lock
            pass
        except BlockingIOError:
            raise FolderInUse(
                f"{folder} is in use by another moegs command (it holds the folder's lock); wait for it to "
                f"end or choose another {flag}"
            ) from None
        yield folder
    finally:
        os.close(fd)
        if made:
            try:
                folder.rmdir()  # only an empty folder: nothing was written
            except OSError:
                pass


def clear_folder(folder: Path) -> None:
    """Remove what ``folder`` holds, keeping the folder (and the lock held on it)."""
    import shutil

    for path in folder.iterdir():
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def check_distinct(items: list, flag: str, key: Callable[[Any], Any] = lambda item: item) -> None:
    """Refuse a list that names something twice (``key`` says what is the same: a folder's resolved path):
    ``ValueError`` naming ``flag`` and the duplicates as given."""
    seen, twice = set(), []
    for item in items:
        if key(item) in seen and key(item) not in {key(t) for t in twice}:
            twice.append(item)
        seen.add(key(item))
    if twice:
        names = ", ".join(repr(str(t)) for t in twice)
        raise ValueError(f"{flag} names {names} more than once (a duplicate); give each once")
