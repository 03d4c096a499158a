"""The CUDA code path of training, on the CPU: every expert trains with ``backend="cuda"`` through our gsplat
glue (gsplat's own torch kernels on CPU tensors, ``helpers.gsplat_reference.install_cpu_glue``), with the
GPU's cadence of finite checks (every ``log_every`` steps). Densification then runs on gsplat's statistics
(its projected means' gradient, its radii) as it does on a GPU.

What a CPU cannot show: that tensors are on the right device (``test_device_*`` files, under a poisoned
default device), and real CUDA numerics and speed (``bench/gpu/train_check.sh`` on a lent GPU).
"""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from helpers.gsplat_reference import install_cpu_glue
from helpers.protocol import build
from helpers.training import builtin_experts

from moegs.io import load_checkpoint, read_json, save_checkpoint
from moegs.train.checkpoint import CHECKPOINT_NAME
from moegs.train.loop import NonFiniteError, TrainingRun, train

STEPS = 12


def _run(name: str, backend: str, check_every: int) -> tuple[list[float], list[int], list[str]]:
    """``STEPS`` steps of ``name`` at its quick preset on the tiny scene: losses, Gaussian counts and the
    backends that rendered."""
    expert, scene = build(name)
    config = replace(expert.config.train, iterations=STEPS, backend=backend, log_every=check_every)
    run = TrainingRun(expert, scene, config, None)
    run.check_every = check_every
    torch.manual_seed(config.seed)
    counts, backends = [], set()
    expert.train()
    for step in range(1, STEPS + 1):
        run.pending.append(run.iteration(step))
        counts.append(expert.num_gaussians)
        backends.add(expert.render(scene.train[0].camera, scene.background, backend)[1].info["backend"])
    return run.read_history(), counts, sorted(backends)


@pytest.mark.parametrize("name", builtin_experts())
def test_every_expert_trains_through_the_cuda_glue(name, monkeypatch):
    install_cpu_glue(monkeypatch)
    cpu_losses, cpu_counts, _ = _run(name, "cpu", 1)
    losses, counts, backends = _run(name, "cuda", 4)
    assert backends == ["cuda"]
    assert all(torch.isfinite(torch.tensor(losses))), losses
    # gsplat and 3DGS differ in their clamps and screen radii (moegs/render/_cuda.py), so the two runs
    # are not equal; the first step renders the same Gaussians and must give nearly the same loss
    assert losses[0] == pytest.approx(cpu_losses[0], rel=0.05), (losses[0], cpu_losses[0])
    assert counts[0] == cpu_counts[0]
    if counts != cpu_counts:  # densification saw gsplat's statistics: same direction, similar size
        assert (counts[-1] - counts[0]) * (cpu_counts[-1] - cpu_counts[0]) >= 0, (counts, cpu_counts)


def test_a_gpu_cadence_run_names_the_unchecked_steps_and_never_saves_a_nan(tmp_path):
    """Between its checks (every ``log_every`` steps on a GPU) a NaN is found at the next check, which says
    since when it went unchecked; the checkpoint written after it is refused before it holds the NaN."""
    expert, scene = build("static")
    config = replace(expert.config.train, iterations=8, log_every=4, checkpoint_every=3)
    run = TrainingRun(expert, scene, config, None)
    run.check_every = 4
    for step in (1, 2):
        run.pending.append(run.iteration(step))
        run.step = step
    with torch.no_grad():
        expert.splats["means"][0, 0] = float("nan")
    with pytest.raises(NonFiniteError, match=r"step 3: parameter .* \(unchecked since step 0"):
        run.step = 3
        run.save(tmp_path / "checkpoint.safetensors")
    assert not (tmp_path / "checkpoint.safetensors").exists()


def test_the_gpu_cadence_changes_when_values_are_read_never_what_is_computed():
    """Checks and loss read-backs every 5 steps give the same history and model as every step."""
    results = []
    for every in (1, 5):
        expert, scene = build("deformable")
        run = TrainingRun(expert, scene, replace(expert.config.train, iterations=11), None)
        run.check_every = every
        for step in range(1, 12):
            run.pending.append(run.iteration(step))
            run.step = step
            if step % every == 0:
                run.read_history()
        results.append((run.read_history(), expert.num_gaussians, expert.splats["means"].detach()))
    (history_a, n_a, means_a), (history_b, n_b, means_b) = results
    assert history_a == history_b and len(history_a) == 11
    assert n_a == n_b and torch.equal(means_a, means_b)


def test_a_run_records_its_device_and_refuses_to_resume_on_another(tmp_path):
    expert, scene = build("static")
    config = replace(expert.config.train, iterations=4)
    result = train(expert, scene, config, tmp_path, stop_after=2, progress=False, device="cpu")
    assert result["device"] == "cpu"
    record = read_json(tmp_path / "config.json", "run config")
    assert (record["device"], record["gpu"]) == ("cpu", None)
    state = load_checkpoint(tmp_path / CHECKPOINT_NAME)
    assert state["device"] == "cpu"
    save_checkpoint(tmp_path / CHECKPOINT_NAME, {**state, "device": "cuda:0"})  # as if trained on a GPU
    expert, scene = build("static")
    with pytest.raises(ValueError, match=r"was trained on cuda:0; resuming it on cpu would mix devices"):
        train(expert, scene, config, tmp_path, progress=False)
