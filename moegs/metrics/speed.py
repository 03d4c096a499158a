"""The speed and memory protocol behind every FPS / memory number of the suite.

Rules (``specs/peers_and_style.md`` C.3): time the render call only (no data loading, no metrics, no
saving); warm up first; on CUDA synchronize before starting the clock and before stopping it; take
the median over repeats per view and the median over views; say which device.

Memory, two different quantities, recorded with their kind:

- ``"cuda_max_allocated"``: ``torch.cuda.max_memory_allocated`` over the timed renders, after
  ``reset_peak_memory_stats``: the peak of tensors held by PyTorch's allocator, *including* what is
  already resident (the model's Gaussians), excluding the CUDA context and allocator cache. This is
  the number to compare across runs; ``nvidia-smi`` figures are larger.
- ``"cpu_rss_peak_delta"``: growth of the process resident set over the timed renders: peak RSS
  (``VmHWM``, reset through ``/proc/self/clear_refs``) minus RSS before. Counts every allocation of
  the process (numpy, torch, C++), not only tensors, and excludes memory that was already resident
  (including freed memory the allocator hands out again: measure in a fresh process for absolutes).
- ``"cpu_maxrss_delta"`` (fallback where the peak cannot be reset): growth of
  ``getrusage().ru_maxrss``, a lower bound that stays 0 while the process's earlier peak is higher.
"""

from __future__ import annotations

import mmap
import platform
import resource
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import cache
from typing import Any

import torch


@dataclass(frozen=True)
class SpeedResult:
    """Timing of ``fn(view)`` over views; all times in milliseconds."""

    fps_median: float
    """``1000 / ms_per_view_median``."""
    ms_per_view_median: float
    """Median over views of each view's median over repeats."""
    per_view_ms: list[float]
    """Each view's median over ``repeats`` timed calls."""
    peak_memory_mb: float | None
    """See ``memory_kind``; MiB (2**20 bytes). ``None`` if it could not be read."""
    memory_kind: str
    device: str
    """Device and hardware name, e.g. ``cuda:0 (NVIDIA H100 80GB HBM3)`` or ``cpu (x86_64, 2 threads)``."""
    warmup: int
    repeats: int
    samples_ms: list[list[float]] = field(repr=False)
    """Every timed call, ``[view][repeat]``."""

    def to_dict(self) -> dict:
        return asdict(self)


def _first_tensor_device(obj: Any, depth: int = 3) -> torch.device | None:
    """Device of the first tensor in a render output (tensor, or dict/list/tuple/object holding one)."""
    if isinstance(obj, torch.Tensor):
        return obj.device
    if depth == 0:
        return None
    if isinstance(obj, dict):
        items = obj.values()
    elif isinstance(obj, list | tuple):
        items = obj
    elif hasattr(obj, "__dict__"):
        items = vars(obj).values()
    else:
        return None
    for item in items:
        dev = _first_tensor_device(item, depth - 1)
        if dev is not None:
            return dev
    return None


def _describe(device: torch.device) -> str:
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return f"{device.type} ({platform.machine()}, {torch.get_num_threads()} threads)"


def _status_kb(key: str) -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset the process's ``VmHWM`` to its current RSS (Linux >= 4.0); ``False`` if not possible.

    Some kernels and sandboxes accept the write to ``clear_refs`` and ignore it, or never raise
    ``VmHWM`` afterwards; a one-time probe (touch and free 32 MiB) checks that the reset lowers the
    mark and that an allocation then raises it again.
    """
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    hwm, rss = _status_kb("VmHWM"), _status_kb("VmRSS")
    return hwm is not None and rss is not None and hwm <= rss + 1024 and _peak_rss_tracks_allocations()


@cache
def _peak_rss_tracks_allocations() -> bool:
    probe_kb = 32 * 1024
    before = _status_kb("VmHWM")
    with mmap.mmap(-1, probe_kb * 1024) as probe:  # fresh pages (malloc may reuse resident memory)
        probe[::4096] = b"\x01" * (probe_kb // 4)
    after = _status_kb("VmHWM")
    if before is None or after is None or after - before < probe_kb // 2:
        return False
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    return True


def _maxrss_kb() -> int:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss // 1024 if platform.system() == "Darwin" else rss  # bytes on macOS, KiB on Linux


def measure_render(
    fn: Callable[[Any], Any],
    views: Sequence[Any],
    warmup: int = 2,
    repeats: int = 3,
    device: str | torch.device | None = None,
) -> SpeedResult:
    """Time ``fn(view)`` for every view.

    Args:
        fn: the render call only, e.g. ``lambda cam: rasterize(frame, cam)``; its output is discarded.
        views: cameras (anything ``fn`` takes); at least one.
        warmup: untimed calls before timing, cycling through the views.
        repeats: timed calls per view (the view's time is their median).
        device: where ``fn`` computes; ``None`` infers it from the first tensor in the first warm-up
            output (so ``warmup >= 1`` is then required), CPU if none.

    Returns:
        ``SpeedResult``.
    """
    if len(views) == 0:
        raise ValueError("measure_render: `views` is empty")
    if warmup < 0 or repeats < 1:
        raise ValueError(
            f"measure_render: need warmup >= 0 and repeats >= 1, got warmup={warmup}, repeats={repeats}"
        )
    if device is None and warmup == 0:
        raise ValueError(
            "measure_render: `device=None` infers the device from a warm-up call; pass warmup >= 1"
        )

    inferred = None
    for i in range(warmup):
        out = fn(views[i % len(views)])
        if i == 0:
            inferred = _first_tensor_device(out)
        del out
    dev = torch.device(device) if device is not None else (inferred or torch.device("cpu"))
    cuda = dev.type == "cuda"

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize(dev)

    if cuda:
        sync()
        torch.cuda.reset_peak_memory_stats(dev)
        memory_kind = "cuda_max_allocated"
    else:
        rss_before = _status_kb("VmRSS")
        hwm = rss_before is not None and _reset_peak_rss()
        memory_kind = "cpu_rss_peak_delta" if hwm else "cpu_maxrss_delta"
        maxrss_before = _maxrss_kb()

    samples: list[list[float]] = []
    for view in views:
        times = []
        for _ in range(repeats):
            sync()
            start = time.perf_counter_ns()
            out = fn(view)
            sync()
            times.append((time.perf_counter_ns() - start) / 1e6)
            del out
        samples.append(times)

    if cuda:
        peak = torch.cuda.max_memory_allocated(dev) / 2**20
    elif memory_kind == "cpu_rss_peak_delta":
        hwm_after = _status_kb("VmHWM")
        peak = None if hwm_after is None else max(hwm_after - rss_before, 0) / 1024
    else:
        peak = max(_maxrss_kb() - maxrss_before, 0) / 1024

    per_view = [statistics.median(t) for t in samples]
    ms = statistics.median(per_view)
    return SpeedResult(
        fps_median=1000.0 / ms if ms > 0 else float("inf"),
        ms_per_view_median=ms,
        per_view_ms=per_view,
        peak_memory_mb=peak,
        memory_kind=memory_kind,
        device=_describe(dev),
        warmup=warmup,
        repeats=repeats,
        samples_ms=samples,
    )
