"""Stage 2 of MoE-GS: train the router over frozen experts, evaluate the blend.

Per 1-based iteration (one training view per step, shuffled over all cameras and frames, as the code's
``mini_batch: 1``)::

    lr = schedules(step)                      # w, w_dir: 0.5 decayed; w_time and Phi: 0.05 constant
    out = model.render(view.camera)           # experts + weight maps in one pass, router, blend
    loss = (1 - 0.2) L1(out.image, gt) + 0.2 (1 - SSIM)
    backward; RAdam step                      # only router parameters have gradients
    every prune_every steps (if set): gate-aware pruning of experts and router (``moegs.moe.prune``)

Example::

    >>> result = train_router([ex4dgs, stg], scene, RouterConfig.from_preset("quick"), "runs/moe")
    >>> result["test"]["psnr"], [e["psnr"] for e in result["test"]["experts"]]
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from moegs.data.scene import ImageCache, Scene, View
from moegs.device import device_name, gpu_model
from moegs.experts.base import Expert, splat_inputs_bytes
from moegs.io import from_dict, save_checkpoint, to_dict, write_json
from moegs.io.config import config_changes
from moegs.moe.config import RouterConfig
from moegs.moe.model import ROUTER_CHECKPOINT, MoEGS, _check_experts, apply_kept, read_router, winner_share
from moegs.moe.prune import WeightGradients, keep_gaussians
from moegs.train.evaluate import eval_views, evaluate_renderer
from moegs.train.losses import photometric
from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup
from moegs.train.sampler import ViewSampler
from moegs.train.stopping import raise_if_stopped, stop_requests

INPUTS_CACHE_BYTES = 2 << 30
"""Default memory for the frozen experts' rasterizer inputs during router training (2 GiB)."""
RADAM_EPS = 1e-8
"""The code builds ``torch.optim.RAdam(..., lr=0.001)`` with torch's default eps (kept with Adam too)."""
LOG_EVERY = 10
"""Router steps between reads of the loss history from the device (and its finiteness check)."""


def router_param_groups(model: MoEGS) -> list[ParamGroup]:
    """Groups with the paper's rates (RAdam in the code); only ``w`` (w, w_dir) is decayed (code ``f_m``)."""
    c = model.config
    rates = {
        "w": {"lr": c.lr_w, "lr_final": c.lr_w * c.lr_w_final_ratio, "max_steps": c.decay_steps},
        "w_time": {"lr": c.lr_time},
        "phi": {"lr": c.lr_phi},
    }
    return [
        ParamGroup(name, params, optimizer=c.optimizer, eps=RADAM_EPS, **rates[name])
        for name, params in model.router.param_groups().items()
    ]


@torch.no_grad()
def evaluate_moe(model: MoEGS, views: Sequence[View], background, profile: str = "moegs") -> dict[str, Any]:
    """``evaluate_renderer`` of the blend, with every expert's image of the same render as a component,
    and the share of pixels each expert wins; ``views`` and ``background`` on the model's device.

    Returns:
        ``evaluate_renderer``'s dict without ``components``, plus ``"experts": [{"name", **KEYS}]`` and
        ``"winner_share": [K floats]``.
    """
    if not views:
        raise ValueError("evaluate_moe needs at least one view")
    shares = []

    def render(camera):
        out = model.render(camera, background)
        shares.append(winner_share(out.gates))
        return out.image, {str(k): image for k, image in enumerate(out.expert_images)}

    scores = evaluate_renderer(render, views, profile)
    components = scores.pop("components")
    scores["experts"] = [{"name": e.name, **components[str(k)]} for k, e in enumerate(model.experts)]
    scores["winner_share"] = torch.stack(shares).mean(0).tolist()
    return scores


class LossHistory:
    """The loss of every router step: ``values`` (floats) and the steps not read back yet, kept on the
    device. ``read()`` turns those into floats in one host read (every ``LOG_EVERY`` steps, before a
    checkpoint and at the end) and raises ``FloatingPointError`` naming the first non-finite one's step
    and view, so no checkpoint holds a NaN."""

    def __init__(self, values: list[float]) -> None:
        self.values = values
        self.pending: list[tuple[int, str, Tensor]] = []

    def add(self, step: int, view: View, loss: Tensor) -> None:
        self.pending.append((step, view.key, loss))

    def read(self) -> list[float]:
        if self.pending:
            pending, self.pending = self.pending, []
            losses = torch.stack([loss for _, _, loss in pending]).tolist()
            for (step, key, _), value in zip(pending, losses, strict=True):
                if not math.isfinite(value):
                    raise FloatingPointError(
                        f"router step {step}: loss of view {key} is {value} (losses are read back every "
                        f"{LOG_EVERY} steps; this read ran after step {pending[-1][0]})"
                    )
            self.values.extend(losses)
        return self.values


def router_step(
    model: MoEGS,
    view: View,
    background,
    frozen: ImageCache,
    optimizers: Optimizers,
    step: int,
    gradients: WeightGradients | None = None,
) -> Tensor:
    """One router iteration on ``view`` (scene placed on the model's device): render, loss, backward,
    (``gradients`` add theirs), optimiser step. Returns the loss, detached and not read back."""
    optimizers.set_step(step)
    inputs = model.expert_inputs(view.camera, background, frozen)
    rendered = model.render(view.camera, background, inputs=inputs)
    loss = photometric(rendered.image, view.image(), model.config.lambda_dssim)
    loss.backward()
    if gradients is not None:
        gradients.add(model)
    optimizers.step()
    optimizers.zero_grad()
    return loss.detach()


def _state(
    model: MoEGS,
    scene: Scene,
    step: int,
    optimizers: Optimizers,
    sampler: ViewSampler,
    history: LossHistory,
    gradients: WeightGradients | None,
):
    return {
        **model.checkpoint_state(),
        "scene": scene.identity(),
        "step": step,
        "optimizers": optimizers.state_dict(),
        "sampler": sampler.state_dict(),
        "rng": {"torch": torch.get_rng_state()},
        "history": list(history.read()),
        "weight_gradients": None if gradients is None else gradients.state_dict(),
    }


def prune_step(config: RouterConfig, step: int) -> bool:
    """Whether router iteration ``step`` ends with a pruning (never the last)."""
    return (
        bool(config.prune_every)
        and config.prune_from <= step < config.iterations
        and ((step - config.prune_from) % config.prune_every == 0)
    )


def train_router(
    experts: Sequence[Expert],
    scene: Scene,
    config: RouterConfig | None = None,
    out_dir: str | Path | None = None,
    *,
    resume: bool = True,
    progress: bool = False,
    stop_after: int | None = None,
    inputs_cache_bytes: int = INPUTS_CACHE_BYTES,
) -> dict[str, Any]:
    """Train a router over the frozen ``experts`` on ``scene``'s training views, then evaluate.

    Args:
        experts: trained experts (frozen: no parameter of theirs trains; pruning while training, or
            resuming such a run, removes Gaussians from them in place), on the device to train on: the
            router is built there and the losses are read back every ``LOG_EVERY`` steps.
        scene: the scene they were trained on (cameras and images are placed beside the experts).
        config: router settings (default: the ``quick`` preset).
        out_dir: where ``router.safetensors`` (resumable), ``config.json`` and ``metrics.json`` go.
        resume: continue from ``out_dir``'s checkpoint when there is one.
        progress: show a tqdm bar.
        stop_after: stop with a checkpoint after this iteration, as if interrupted.
        inputs_cache_bytes: memory for the experts' rasterizer inputs, kept per ``splat_inputs_key`` (one
            per training time for most experts) instead of recomputed every step; 0 keeps none. The
            result is the same either way.

    Returns:
        ``{"router", "experts", "scene", "stand_in", "completed", "step", "iterations", "train_seconds",
        "final_loss", "resumed_from", "test" (``evaluate_moe``; None when stopped early)}``, and
        "pruned_fraction" (of the experts' Gaussians) when ``config.prune_every`` pruned. The experts are
        pruned in place then (and on a resume of such a run).
    """
    config = config or RouterConfig.from_preset("quick")
    out = Path(out_dir) if out_dir is not None else None
    ckpt = out / ROUTER_CHECKPOINT if out is not None else None
    state = read_router(ckpt) if resume and ckpt is not None and ckpt.is_file() else None
    if state is not None:  # every check first: a refused resume leaves the experts as they were
        _check_experts(state, experts, ckpt)
        scene.check_identity(state.get("scene"), ckpt, tuple(scene.identity()))
        saved = to_dict(from_dict(RouterConfig, state["config"]))  # fields added since: their defaults
        changed = config_changes(saved, to_dict(config), ("checkpoint_every",))
        if changed:
            raise ValueError(
                f"{ckpt} was written with another router config (changed: {', '.join(changed[:6])}); "
                "use a new out_dir or resume=False"
            )
        apply_kept(experts, state.get("kept"))  # a run pruned while training goes on from its pruned experts
    torch.manual_seed(config.seed)
    model = MoEGS(experts, config)
    model.kept = None if state is None else state.get("kept")
    scene = scene.to(model.device)
    frozen = ImageCache(max_bytes=inputs_cache_bytes, nbytes=splat_inputs_bytes)
    optimizers = Optimizers(router_param_groups(model))
    sampler = ViewSampler([0] * len(scene.train), 1, config.seed)
    gradients = WeightGradients(model) if config.prune_every else None
    with stop_requests(out is not None) as stop:  # SIGINT/SIGTERM: checkpoint, then stop
        done, history, resumed_from = 0, LossHistory([]), None
        if state is not None:
            model.router.load_state_dict(state["router"])
            optimizers.load_state_dict(state["optimizers"])
            sampler.load_state_dict(state["sampler"])
            torch.set_rng_state(state["rng"]["torch"])
            done = resumed_from = state["step"]
            history = LossHistory(list(state["history"]))
            if gradients is not None:
                gradients.load_state_dict(state["weight_gradients"])
        if out is not None:
            write_json(
                out / "config.json",
                {
                    "router": to_dict(config),
                    "experts": [e.name for e in experts],
                    "scene": scene.name,
                    "stand_in": scene.stand_in,
                    "device": device_name(model.device),
                    "gpu": gpu_model(model.device),
                },
            )

        last = config.iterations if stop_after is None else min(stop_after, config.iterations)
        names = "+".join(e.name for e in experts)
        bar = tqdm(
            range(done + 1, last + 1),
            initial=done,
            total=config.iterations,
            disable=not progress,
            desc=f"{config.variant} router over {names}",
            dynamic_ncols=True,
        )
        seconds = 0.0
        model.train()
        for step in bar:
            if stop["signal"] is not None:
                break
            start = time.perf_counter()
            view = scene.train[sampler.next()[0]]
            try:
                loss = router_step(model, view, scene.background, frozen, optimizers, step, gradients)
            except FloatingPointError as err:  # the rasterizer names a non-finite input: an earlier NaN loss?
                history.read()
                raise FloatingPointError(f"router step {step}: view {view.key}: {err}") from err
            history.add(step, view, loss)
            done = step
            if gradients is not None and prune_step(config, step):
                keep = gradients.prune_masks(config.prune_threshold)
                keep_gaussians(model, keep, optimizers)
                gradients.restart(keep)
                frozen = ImageCache(max_bytes=inputs_cache_bytes, nbytes=splat_inputs_bytes)
            seconds += time.perf_counter() - start
            if step % LOG_EVERY == 0:
                bar.set_postfix(loss=f"{history.read()[-1]:.4f}")
            if ckpt is not None and config.checkpoint_every and step % config.checkpoint_every == 0:
                save_checkpoint(ckpt, _state(model, scene, step, optimizers, sampler, history, gradients))
        bar.close()
        history.read()
        if ckpt is not None:
            save_checkpoint(ckpt, _state(model, scene, done, optimizers, sampler, history, gradients))

    raise_if_stopped(stop, done, config.iterations, ckpt)

    model.eval()
    completed = done >= config.iterations
    test_views = eval_views(scene.test, config.max_eval_views)
    test = evaluate_moe(model, test_views, scene.background, config.metric_profile) if completed else None
    result = {
        "router": config.variant,
        "experts": [e.name for e in experts],
        "scene": scene.name,
        "stand_in": scene.stand_in,
        "device": device_name(model.device),
        "completed": completed,
        "step": done,
        "iterations": config.iterations,
        "train_seconds": seconds,
        "final_loss": history.values[-1] if history.values else None,
        "resumed_from": resumed_from,
        "test": test,
    }
    if model.kept is not None:
        trained = sum(int(m.numel()) for m in model.kept)
        result["pruned_fraction"] = 1.0 - model.num_gaussians / max(trained, 1)
    if out is not None:
        write_json(out / "metrics.json", result)
    return result
