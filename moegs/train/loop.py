"""The one training loop shared by every expert.

Per 1-based iteration ``step`` (3DGS ``iteration``)::

    expert.on_step(step)                   # stage switch -> fresh optimisers from param_groups()
    lr = schedules(step)
    views = expert.select_views(...) or one batch per view group   # ViewSampler
    loss = mean over views of photometric(expert.render(...), gt) + expert.regularization(step, frame)
                                 + expert.observe(step, view, rgb, gt, out)
    strategy.step_pre_backward ; loss.backward() ; strategy.step_post_backward   # 3DGS densifies here
    optimiser step (skipped at the last iteration, as in 3DGS ``if iteration < opt.iterations``)
    strategy.step_post_optimizer           # 3DGS-MCMC noise
    NaN/Inf checks, checkpoint, evaluation

The run computes on one device (``device=``): the expert is moved there once, the scene placed there
(``Scene.to``). On the CPU the NaN/Inf checks run every step; on a GPU, where each check waits for the
device, they run every ``log_every`` steps, before every checkpoint and at the last step (a checkpoint never
holds a non-finite value), and the loss history is read back at the same steps.

Example::

    >>> expert = get_expert_class("static").from_scene(scene, StaticConfig.from_preset("quick"))
    >>> result = train(expert, scene, out_dir="runs/static-mutant")
    >>> result["test"]["psnr"]
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from moegs.data.scene import Scene, View
from moegs.device import device_name, gpu_model, resolve_device
from moegs.experts.base import Expert
from moegs.io import save_checkpoint, to_dict, write_json
from moegs.io.config import config_changes
from moegs.render.pipeline import value_checks
from moegs.train.checkpoint import (
    CHECKPOINT_NAME,
    check_device,
    read_checkpoint,
    restore_model,
    restore_rng,
    training_state,
)
from moegs.train.config import TrainConfig
from moegs.train.evaluate import eval_views, evaluate, render_view
from moegs.train.losses import photometric
from moegs.train.memory import keep_freed_memory
from moegs.train.optim import Optimizers
from moegs.train.sampler import ViewSampler
from moegs.train.select import BestModel
from moegs.train.stopping import raise_if_stopped, stop_requests

ViewLoss = Callable[[View, torch.Tensor, torch.Tensor, float], torch.Tensor]
"""``(view, rgb [H, W, 3], target [H, W, 3], lambda_dssim) -> loss`` (see ``train(loss=...)``)."""


RUN_ONLY_FIELDS = ("train.checkpoint_every", "train.eval_every", "train.log_every", "train.select_best_at")
"""Config fields that do not change what a run computes: a checkpoint resumes under other values."""


class NonFiniteError(FloatingPointError):
    """Training produced NaN/Inf; the message names the step, the tensor and the last good checkpoint."""


def _check_finite(
    step: int, what: str, tensors: dict[str, torch.Tensor | None], last_good: str, since: int | None = None
) -> None:
    """Raise ``NonFiniteError`` naming the first tensor holding NaN/Inf (one fused test if all finite);
    ``since``: the last checked step, when the steps after it were not checked."""
    present = {k: v for k, v in tensors.items() if v is not None and v.is_floating_point()}
    if not present or torch.stack([v.detach().sum().float() for v in present.values()]).isfinite().all():
        return  # a finite sum of finite values; NaN/Inf (or an overflowing sum) goes on to the exact test
    unchecked = since is not None and since < step - 1
    arose = f" (unchecked since step {since}: it arose after it)" if unchecked else ""
    for name, value in present.items():
        if not torch.isfinite(value).all():
            bad = int((~torch.isfinite(value)).sum())
            raise NonFiniteError(
                f"step {step}: {what} {name} has {bad} NaN/Inf value(s) of {value.numel()}{arose}; "
                f"training stopped. {last_good}"
            )


class TrainingRun:
    """Mutable state of one training run; :func:`train` drives it, ``iteration(step)`` runs one step
    (``bench.profile`` times those steps directly). The run computes where the expert's parameters are;
    ``scene`` is placed there."""

    def __init__(self, expert: Expert, scene: Scene, config: TrainConfig, loss: ViewLoss | None) -> None:
        self.device = next(expert.parameters()).device
        self.expert, self.scene, self.config = expert, scene.to(self.device), config
        self.loss = loss
        scene = self.scene
        self.strategy = expert.strategy()
        self.optimizers = Optimizers(expert.param_groups())
        white = bool((scene.background >= 1.0).all())
        self.strategy_state = self.strategy.initialize_state(scene.extent, white) if self.strategy else {}
        if self.strategy:
            self.strategy_state.update(expert.strategy_inputs(scene))
        groups = expert.view_groups(scene.train) or [0] * len(scene.train)
        self.sampler = ViewSampler(groups, config.batch_size, config.seed)
        self.step = 0
        self.seconds = 0.0
        self.history: list[float] = []
        self.pending: list[torch.Tensor] = []  # losses of the steps since the history was last read
        self.checked_step = 0  # the last step whose loss, gradients and parameters were checked
        self.check_every = 1 if self.device.type == "cpu" else config.log_every  # see module docstring
        self.saved_step: int | None = None
        self.last_good = "No checkpoint was written yet."

    def checks_at(self, step: int) -> bool:
        """Whether ``step`` checks for NaN/Inf: every ``check_every``-th step and the last one."""
        return step % self.check_every == 0 or step == self.config.iterations

    def read_history(self) -> list[float]:
        """The loss of every finished step (reads the pending ones back from the device)."""
        if self.pending:
            self.history.extend(torch.stack(self.pending).tolist())
            self.pending = []
        return self.history

    def check_parameters(self) -> None:
        """NaN/Inf test of the parameters after ``self.step`` unless that step was checked."""
        if self.checked_step != self.step:
            params = dict(self.expert.named_parameters())
            _check_finite(self.step, "parameter", params, self.last_good, self.checked_step)
            self.checked_step = self.step

    def splat_optimizers(self) -> dict:
        return self.optimizers.for_splats(self.expert.splats)

    # -- checkpoints ------------------------------------------------------------------------------
    def save(self, path: Path) -> None:
        """Write the run's checkpoint: it is the last good one from now on."""
        self.write(path)
        self.saved_step = self.step
        self.last_good = f"Last good checkpoint: {path} (step {self.step})."

    def write(self, path: Path) -> None:
        """Write the run's state to ``path`` (a checkpoint, or a copy such as the best model's)."""
        self.check_parameters()  # a checkpoint never holds NaN/Inf
        save_checkpoint(
            path,
            training_state(
                self.expert,
                self.step,
                self.optimizers.state_dict(),
                self.strategy_state,
                self.sampler.state_dict(),
                self.read_history(),
                self.seconds,
                self.scene,
            ),
        )

    def resume(self, path: Path) -> None:
        state = read_checkpoint(path)
        if state["expert"]["name"] != self.expert.name:
            raise ValueError(f"{path} holds a {state['expert']['name']!r} run, not {self.expert.name!r}")
        changed = config_changes(state["expert"]["config"], to_dict(self.expert.config), RUN_ONLY_FIELDS)
        if changed:
            raise ValueError(
                f"{path} was written with another config (changed: {', '.join(changed[:6])}); "
                "use a new out_dir or resume=False (moegs train --no-resume)"
            )
        check_device(state, self.device, path)
        self.scene.check_identity(state.get("scene"), path, tuple(self.scene.identity()))
        restore_model(self.expert, state["model"])
        self.step = self.checked_step = state["step"]
        self.expert.on_step(self.step)  # replays the stage of the last finished step
        self.optimizers = Optimizers(self.expert.param_groups())
        self.optimizers.load_state_dict(state["optimizers"])
        self.strategy_state = state["strategy_state"]
        self.sampler.load_state_dict(state["sampler"])
        restore_rng(state["rng"], self.device)
        self.history, self.pending = list(state["history"]), []
        self.seconds = float(state.get("seconds", 0.0))
        self.saved_step = self.step
        self.last_good = f"Last good checkpoint: {path} (step {self.step})."

    # -- one iteration ----------------------------------------------------------------------------
    def iteration(self, step: int) -> torch.Tensor:
        """Run training step ``step``; returns its loss (0-dim, detached, on the run's device)."""
        check = self.checks_at(step)
        with value_checks(check):
            loss = self._iteration(step, check)
        if check:
            self.checked_step = step
        return loss

    def _iteration(self, step: int, check: bool) -> torch.Tensor:
        expert, config, strategy = self.expert, self.config, self.strategy
        since = self.checked_step
        if expert.on_step(step):
            self.optimizers = Optimizers(expert.param_groups())
        self.optimizers.set_step(step)
        picked = expert.select_views(step, self.scene.train, config.batch_size, self.sampler.generator)
        if picked is None:
            picked = self.sampler.next()
            expert.on_views(self.sampler.left)
        views = [self.scene.train[i] for i in picked]
        splat_opts = self.splat_optimizers() if strategy else {}
        info: dict[str, Any] = {"renders": [], "views": []}
        if strategy:
            strategy.step_pre_backward(expert.splats, splat_opts, self.strategy_state, step, info)

        needs_stats = bool(strategy and strategy.needs_render_stats)
        loss = 0.0
        for view in views:
            cam = view.camera
            try:
                rgb, out, frame = render_view(expert, cam, self.scene.background, config.backend, needs_stats)
            except FloatingPointError as err:  # the rasterizer names the non-finite field of the frame
                raise NonFiniteError(
                    f"step {step}: view {view.key}: {err}; training stopped. {self.last_good}"
                ) from err
            target = view.image()
            data_loss = (
                photometric(rgb, target, config.lambda_dssim)
                if self.loss is None
                else self.loss(view, rgb, target, config.lambda_dssim)
            )
            view_loss = data_loss + expert.regularization(step, frame)
            extra = expert.observe(step, view, rgb, target, out)
            if extra is not None:
                view_loss = view_loss + extra
            if check:
                _check_finite(step, "loss of view", {view.key: view_loss.detach()}, self.last_good, since)
            loss = loss + view_loss
            if strategy and strategy.needs_views:
                info["views"].append({"camera": cam, "rgb": rgb.detach(), "target": target})
            if needs_stats:
                info["renders"].append(
                    {
                        **{k: out.info[k] for k in ("radii", "visible", "means2d")},
                        "width": cam.width,
                        "height": cam.height,
                    }
                )
        loss = loss / len(views)
        loss.backward()
        if check:
            grads = {n: p.grad for n, p in expert.named_parameters()}
            _check_finite(step, "gradient of", grads, self.last_good, since)

        if strategy:
            strategy.step_post_backward(expert.splats, splat_opts, self.strategy_state, step, info)
        if step < config.iterations:
            self.optimizers.step()
            if strategy:
                strategy.step_post_optimizer(
                    expert.splats, self.splat_optimizers(), self.strategy_state, step, info
                )
        self.optimizers.zero_grad()
        if check:
            _check_finite(step, "parameter", dict(expert.named_parameters()), self.last_good, since)
        return loss.detach()


def write_run_config(
    out_dir: Path,
    name: str,
    scene: Scene,
    config: Any,
    train_config: TrainConfig,
    recipe: dict[str, Any] | None,
    device: torch.device,
) -> None:
    """``out_dir/config.json``: what a run trains (expert ``name``, scene, expert and training configs, and
    the recipe's provenance) and where (``device``, ``gpu``), read by ``moegs.train.reuse`` and ``moegs
    eval``."""
    write_json(
        out_dir / "config.json",
        {
            "expert": name,
            "scene": scene.name,
            "stand_in": scene.stand_in,
            "config": to_dict(config),
            "train": to_dict(train_config),
            "recipe": recipe,
            "device": device_name(device),
            "gpu": gpu_model(device),
        },
    )


def train(
    expert: Expert,
    scene: Scene,
    config: TrainConfig | None = None,
    out_dir: str | Path | None = None,
    *,
    device: torch.device | str | None = None,
    resume: bool = True,
    progress: bool = True,
    stop_after: int | None = None,
    loss: ViewLoss | None = None,
    recipe: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Train ``expert`` on ``scene`` and evaluate it on the test views.

    Args:
        expert: a freshly built expert (``from_scene``); trained in place.
        scene: the scene it was built for (placed on the run's device with ``Scene.to``).
        device: where to train (``moegs.device.resolve_device`` names); the expert is moved there. None:
            where the expert is.
        config: training settings; default ``expert.config.train``.
        out_dir: where ``checkpoint.safetensors``, ``config.json`` and ``metrics.json`` go (None: keep
            nothing on disk).
        resume: continue from ``out_dir``'s checkpoint when there is one (params, optimiser, strategy
            and sampler state, RNG, step).
        progress: show a tqdm bar.
        stop_after: stop (with a checkpoint) after this iteration, as if interrupted; schedules still
            run to ``config.iterations``.
        loss: ``loss(view, rgb, target, lambda_dssim) -> 0-dim`` replacing the photometric loss of each
            view (distillation from MoE-GS); the expert's regularisers are still added.
        recipe: how the config was made (``moegs.recipes.Recipe.provenance()``), saved in ``config.json``.

    Returns:
        ``{"expert", "scene", "stand_in", "completed", "step", "iterations", "num_gaussians",
        "train_seconds", "seconds_per_step", "final_loss", "resumed_from", "test" (see
        ``evaluate``; None when stopped early), "evaluations" (periodic test PSNRs)}``, and "best"
        (``{"step", "test"}`` of the best-scoring model) when ``config.select_best_at`` scored any.

    Raises:
        NonFiniteError: on NaN/Inf in a loss, gradient or parameter; the last checkpoint is kept.
    """
    config = config or expert.config.train
    if device is not None:
        expert.to(resolve_device(device))
    keep_freed_memory()  # no page faults for the buffers every step allocates again
    out = Path(out_dir) if out_dir is not None else None
    ckpt = out / CHECKPOINT_NAME if out is not None else None
    with stop_requests(out is not None) as stop:  # a signal during set-up stops before step 1
        run = TrainingRun(expert, scene, config, loss)
        scene = run.scene
        torch.manual_seed(config.seed)  # the CPU's generator and every GPU's
        resumed_from = None
        if resume and ckpt is not None and ckpt.is_file():
            run.resume(ckpt)
            resumed_from = run.step
        if out is not None:
            write_run_config(out, expert.name, scene, expert.config, config, recipe, run.device)

        last = config.iterations if stop_after is None else min(stop_after, config.iterations)
        test_views = eval_views(scene.test, config.max_eval_views)
        best = BestModel(config.select_best_at if test_views else (), out, resumed_from)
        evaluations, start_seconds = [], run.seconds
        expert.train()
        bar = tqdm(
            range(run.step + 1, last + 1),
            initial=run.step,
            total=config.iterations,
            disable=not progress,
            desc=f"{expert.name} on {scene.name}",
            dynamic_ncols=True,
        )
        for step in bar:
            if stop["signal"] is not None:
                break
            start = time.perf_counter()
            run.pending.append(run.iteration(step))
            run.step = step
            run.seconds += time.perf_counter() - start
            if step % config.log_every == 0:
                bar.set_postfix(loss=f"{run.read_history()[-1]:.4f}", gaussians=expert.num_gaussians)
            if ckpt is not None and config.checkpoint_every and step % config.checkpoint_every == 0:
                run.save(ckpt)
            periodic = bool(config.eval_every) and step % config.eval_every == 0 and bool(test_views)
            selecting = step in best.steps
            if (periodic or selecting) and step < config.iterations:  # the last step: the final test
                scored = evaluate(expert, test_views, scene.background, config.metric_profile, config.backend)
                if periodic:
                    evaluations.append({"step": step, "psnr": scored["psnr"]})
                if selecting:
                    best.offer(step, scored["psnr"], expert, run.write)
                expert.train()
        bar.close()
        if ckpt is not None and run.saved_step != run.step:
            run.save(ckpt)
        run.check_parameters()
    raise_if_stopped(stop, run.step, config.iterations, ckpt)

    completed = run.step >= config.iterations
    expert.eval()
    test = None
    if completed and test_views:
        test = evaluate(expert, test_views, scene.background, config.metric_profile, config.backend)
    if test is not None and run.step in best.steps:
        best.offer(run.step, test["psnr"], expert, run.write)
    best_test = test
    if completed and best.step is not None and best.step != run.step:
        kept = best.expert(scene, run.device)
        best_test = evaluate(kept, test_views, scene.background, config.metric_profile, config.backend)
    steps_run = last - (resumed_from or 0)
    result = {
        "expert": expert.name,
        "scene": scene.name,
        "stand_in": scene.stand_in,
        "completed": completed,
        "step": run.step,
        "iterations": config.iterations,
        "num_gaussians": expert.num_gaussians,
        "train_seconds": run.seconds,
        "seconds_per_step": (run.seconds - start_seconds) / steps_run if steps_run > 0 else None,
        "final_loss": run.read_history()[-1] if run.read_history() else None,
        "device": device_name(run.device),
        "resumed_from": resumed_from,
        "test": test,
        "evaluations": evaluations,
    }
    if completed and best.step is not None:
        result["best"] = {"step": best.step, "test": best_test}
    if out is not None:
        write_json(out / "metrics.json", result)
    return result
