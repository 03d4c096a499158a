"""Where a run computes: ``auto``, ``cpu``, ``cuda`` or ``cuda:<index>``, resolved once per run.

Every trainer (``moegs.train.loop.train``, ``train_router``, ``distill``) and the bench take a device. The
expert is built on the CPU (so that its initialisation draws the same random numbers on every machine) and
moved once; cameras, background and training images are placed beside it (``moegs.data.scene.Scene.to``,
``moegs.train.images``). Library code names the device of every tensor it creates (``device=like.device``
for maths, ``"cpu"`` for draws from a CPU generator) and keeps control flow in Python scalars, so a step
reads values back from the GPU only where a value is needed (finite checks and logging).

CUDA runs are not bit-identical from run to run: gsplat accumulates gradients with atomic adds, whose
order varies. CPU runs are deterministic. The tests compare a CUDA run with the CPU run of the same seed
to a tolerance (``bench/gpu/train_check.sh``), and check device placement on the CPU (tests/train).
"""

from __future__ import annotations

import torch

DEVICES = "auto, cpu, cuda or cuda:<index>"


def resolve_device(spec: str | torch.device | None) -> torch.device:
    """The device ``spec`` names: ``auto`` (or None) is ``cuda`` when torch sees a GPU, else ``cpu``;
    ``cuda`` is the current GPU. Raises ``ValueError`` (one line, before any work) for a malformed name, a
    CUDA device on a machine without CUDA, or a GPU index the machine does not have."""
    if isinstance(spec, torch.device):
        spec = str(spec)
    spec = "auto" if spec is None else spec.strip().lower()
    if spec == "auto":
        return torch.device("cuda", torch.cuda.current_device()) if torch.cuda.is_available() else _cpu()
    if spec == "cpu":
        return _cpu()
    kind, sep, index = spec.partition(":")
    if kind != "cuda" or (sep and not index.isdigit()):
        raise ValueError(f"device {spec!r} is not one of {DEVICES}")
    if not torch.cuda.is_available():
        why = "this torch is a CPU build" if torch.version.cuda is None else "torch sees no GPU"
        raise ValueError(f"device {spec!r}: CUDA is not available here ({why}); use --device cpu or auto")
    count = torch.cuda.device_count()
    gpu = int(index) if sep else torch.cuda.current_device()
    if gpu >= count:
        raise ValueError(
            f"device {spec!r}: this machine has {count} GPU(s) (cuda:0 to cuda:{count - 1}); "
            "CUDA_VISIBLE_DEVICES may hide the others"
        )
    return torch.device("cuda", gpu)


def _cpu() -> torch.device:
    return torch.device("cpu")


def device_name(device: torch.device) -> str:
    """``"cpu"`` or ``"cuda:<i>"``: how a run's ``config.json`` records its device."""
    return "cpu" if device.type == "cpu" else f"{device.type}:{device.index or 0}"


def device_kind(device: torch.device | str) -> str:
    """``"cpu"`` or ``"cuda"``: what decides a run's numbers (two GPUs of one machine compute alike), as the
    bench keys cells with it."""
    return torch.device(device).type


def gpu_model(device: torch.device) -> str | None:
    """The GPU's name (``"NVIDIA H100 80GB HBM3"``), None for the CPU."""
    return torch.cuda.get_device_name(device) if device.type == "cuda" else None
