"""Training checkpoints: everything needed to resume bit-exactly, and to reload a trained expert.

A checkpoint (``moegs.io.save_checkpoint`` file) holds::

    step, expert {name, config}, model (expert.state_dict()), optimizers, strategy_state,
    sampler, rng {torch, cuda (on a GPU)}, history (loss per step), seconds (training time so far),
    device (where it trained: "cpu" or "cuda:<i>"), scene (``Scene.identity``: what it trained on)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from moegs.data.scene import Scene
from moegs.device import device_kind, device_name, resolve_device
from moegs.experts import get_expert_class
from moegs.experts.base import Expert
from moegs.io import from_dict, load_checkpoint, to_dict

CHECKPOINT_NAME = "checkpoint.safetensors"
FORMAT = 1


def training_state(
    expert: Expert,
    step: int,
    optimizers: dict,
    strategy_state: dict,
    sampler: dict,
    history: list[float],
    seconds: float = 0.0,
    scene: Scene | None = None,
) -> dict[str, Any]:
    """The state tree saved by the training loop after iteration ``step`` (``seconds``: training time so
    far, so that a resumed run reports the whole run's time; ``scene``: the scene it trains on); the
    expert's device is the run's."""
    device = next(expert.parameters()).device
    return {
        "format": FORMAT,
        "step": step,
        "expert": {"name": expert.name, "config": to_dict(expert.config)},
        "model": dict(expert.state_dict()),
        "optimizers": optimizers,
        "strategy_state": strategy_state,
        "sampler": sampler,
        "rng": rng_state(device),
        "history": list(history),
        "seconds": float(seconds),
        "device": device_name(device),
        "scene": scene.identity() if scene is not None else None,
    }


def rng_state(device: torch.device) -> dict[str, torch.Tensor]:
    """The random generators a run on ``device`` draws from: the CPU's, and the GPU's on a GPU."""
    state = {"torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def restore_rng(state: dict[str, torch.Tensor], device: torch.device) -> None:
    """Set the generators saved by ``rng_state``."""
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"], device)


def check_device(state: dict[str, Any], device: torch.device, path: str | Path) -> None:
    """Refuse to resume on another kind of device than the checkpoint's (a run computes on one; checkpoints
    from before devices were recorded trained on the CPU)."""
    saved = state.get("device", "cpu")
    if device_kind(saved) != device.type:
        raise ValueError(
            f"{path} was trained on {saved}; resuming it on {device_name(device)} would mix devices in one "
            f"run: pass --device {device_kind(saved)}, or start over (a new out folder or --no-resume)"
        )


def restore_model(expert: Expert, model: dict[str, torch.Tensor]) -> None:
    """Load ``model`` into ``expert``, first resizing ``splats`` to the saved number of Gaussians."""
    for key, param in list(expert.splats.items()):
        saved = model.get(f"splats.{key}")
        if saved is None:
            raise KeyError(f"checkpoint has no 'splats.{key}'; it was written by another expert version")
        expert.splats[key] = nn.Parameter(
            saved.to(param.device, param.dtype).clone(), requires_grad=param.requires_grad
        )
    expert.load_state_dict(model, strict=True)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load a checkpoint file and check its format."""
    state = load_checkpoint(path)
    if state.get("format") != FORMAT:
        raise ValueError(f"{path}: checkpoint format {state.get('format')!r}, this moegs reads {FORMAT}")
    return state


def load_expert(
    path: str | Path, scene: Scene, expect: str | None = None, device: torch.device | str | None = None
) -> tuple[Expert, dict[str, Any]]:
    """Rebuild the trained expert saved at ``path`` (a checkpoint file or its run folder) for ``scene``;
    with ``expect``, a checkpoint of another expert is refused (``ValueError`` naming both). The expert is
    built on the CPU and moved to ``device`` (None: stays on the CPU); any device may read any checkpoint.

    Returns:
        the expert in eval mode (stage and SH degree of its last step) and the checkpoint state.
    """
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    state = read_checkpoint(path)
    name = state["expert"]["name"]
    if expect is not None and name != expect:
        raise ValueError(f"{path} holds a {name!r} checkpoint, but its run says {expect!r}")
    scene.check_identity(state.get("scene"), path)
    cls = get_expert_class(name)
    config = from_dict(cls.config_class, state["expert"]["config"])
    expert = cls.from_scene(scene, config)
    restore_model(expert, state["model"])
    expert.on_step(state["step"])
    if device is not None:
        expert.to(resolve_device(device))
    return expert.eval(), state
