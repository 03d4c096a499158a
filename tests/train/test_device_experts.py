"""Device handling of every built-in expert, checked on the CPU (``moegs.device``; ``helpers.devices``).

* Training steps under ``poisoned_default_device``, across densification, pruning and stage switches: a
  tensor made without naming its device is a ``meta`` tensor there and fails the step (on CUDA it would be a
  CPU tensor and raise, or copy, there).
* Host reads per plain step (no densification or schedule event) within a budget: on CUDA each one waits
  for the GPU. Budgets are the measured counts, so a new read fails the test; ``MINE`` splits them.
* The schedule state that lives on the host (Python scalars checkpointed as extra state) resumes exactly.

The hash grids take their reference encoding, the path a GPU runs (the compiled kernel is CPU-only).
"""

from __future__ import annotations

from collections import Counter

import pytest
import torch
from helpers.devices import HostReads, poisoned_default_device
from helpers.scenes import tiny_scene
from helpers.training import builtin_experts

from moegs.experts import get_expert_class
from moegs.fields.hashgrid import HashGrid
from moegs.io.config import with_fields
from moegs.train.checkpoint import CHECKPOINT_NAME, read_checkpoint
from moegs.train.loop import TrainingRun, train

STEPS = 12
"""Steps 1-2 run as usual, 3-12 poisoned; every case densifies and prunes in there."""
ADC = {"strategy.densify_from": 2, "strategy.densify_every": 5, "strategy.densify_until": 30}
COMMON = {"max_init_points": 100, "train.iterations": 40, "train.sh_degree_interval": 4}
CASES = {  # expert -> (config changes, scene options, plain steps measured)
    "static": ({**ADC, "strategy.reset_every": 6}, {}, (11, 14)),
    "deformable": ({**ADC, "strategy.reset_every": 6, "warm_up": 5}, {}, (11, 14)),
    "grid4d": ({**ADC, "strategy.reset_every": 6, "warm_up": 5}, {}, (11, 14)),
    "fourdgs": (  # the fine stage (fresh optimisers) from step 5
        {
            "coarse_iterations": 4,
            "strategy.coarse_iterations": 4,
            "strategy.densify_from": 1,
            "strategy.densify_every": 5,
            "strategy.densify_until": 30,
            "strategy.prune_from": 1,
            "strategy.prune_every": 5,
            "strategy.reset_every": 20,
        },
        {},
        (11, 12),
    ),
    "mcmc": (
        {
            "strategy.refine_from": 2,
            "strategy.refine_every": 4,
            "strategy.refine_until": 30,
            "strategy.cap_max": 200,
        },
        {},
        (14, 15),
    ),
    "stg": (  # clone/split at 4, opacity prunes after, reset, ω mask, box prune, two guided events
        {
            **ADC,
            "strategy.max_densify_events": 1,
            "strategy.prune_until": 30,
            "strategy.reset_at": (6,),
            "strategy.omega_mask_from": 7,
            "strategy.bbox_prune_at": 9,
            "strategy.guided_from": 3,
            "strategy.guided_gap": 1,
            "strategy.guided_quantile": 0.05,
        },
        {},
        (13, 14),
    ),
    "ed3dgs": (  # error-guided frames on the even steps from 6, D-SSIM at 10
        {
            **ADC,
            "random_until": 5,
            "multiview_ssim_iters": 0,
            "deform_from": 3,
            "anneal_steps": 3,
            "coarse_to_fine_until": 8,
        },
        {},
        (13, 14),
    ),
    "ex4dgs": (  # growths, conversions, temporal-opacity adjustments, pruning at pass starts
        {
            **ADC,
            "interval": 2,
            "time_pad": 1,
            "start_duration": 2,
            "grow_from": 2,
            "grow_every": 3,
            "make_dynamic_interval": 1,
            "extract_every": 7,
            "extract_percentile": 0.5,
            "reg_from": 2,
            "adjust_every": 6,
            "adjust_until": 30,
            "strategy.prune_from": 5,
        },
        {"num_frames": 6},
        (12, 16),
    ),
}

BUDGETS = {
    "deformable": 6,
    "ed3dgs": 10,
    "ex4dgs": 6,
    "fourdgs": 6,
    "grid4d": 6,
    "mcmc": 14,
    "static": 6,
    "stg": 12,
}
"""Host reads of ``moegs`` code per plain step (the most over the measured steps), by expert."""
MINE = {
    "deformable": 0,
    "ed3dgs": 4,
    "ex4dgs": 0,
    "fourdgs": 0,
    "grid4d": 0,
    "mcmc": 0,
    "static": 0,
    "stg": 2,
}
"""Of those, the reads of the experts, their strategies and fields, and the optimisers and view sampler:
E-D3DGS and STG draw their views from the sampler's generator on the host (one or two draws), and E-D3DGS
reads the frame errors back for its error-guided draw (every other step)."""
OWN = (
    "moegs/experts/",
    "moegs/train/strategy/",
    "moegs/fields/",
    "moegs/mode/",
    "moegs/train/set_optim.py",
    "moegs/train/optim.py",
    "moegs/train/sampler.py",
    "moegs/data/points.py",
)


def test_every_builtin_expert_has_a_case():
    assert sorted(CASES) == builtin_experts()


def _build(name: str, **changes):
    """The expert ``name`` at its case's config (with ``changes``) on the case's tiny scene."""
    cls = get_expert_class(name)
    overrides, scene_options, _ = CASES[name]
    config = with_fields(cls.config_class.from_preset("quick"), {**COMMON, **overrides, **changes})
    scene = tiny_scene(**scene_options)
    torch.manual_seed(0)
    return cls.from_scene(scene, config), scene


def _run(name: str) -> TrainingRun:
    expert, scene = _build(name)
    run = TrainingRun(expert, scene, expert.config.train, None)
    expert.train()
    return run


@pytest.fixture
def reference_encoding(monkeypatch):
    """Hash grids encode with ``encode_reference`` (the CUDA path), not the compiled CPU kernel."""
    monkeypatch.setattr(HashGrid, "forward", HashGrid.encode_reference)


@pytest.mark.parametrize("name", sorted(CASES))
def test_training_names_the_device_of_every_tensor(name, reference_encoding):
    run = _run(name)
    start = run.expert.num_gaussians
    for step in range(1, STEPS + 1):
        if step <= 2:
            run.iteration(step)
        else:
            with poisoned_default_device():
                run.iteration(step)
    assert run.expert.num_gaussians != start  # densified or pruned under the poison
    if name == "ex4dgs":
        assert run.expert.splats["dynamic"].any() and run.expert.keyframes > 0  # converted, grown


@pytest.mark.parametrize("name", sorted(CASES))
def test_host_reads_per_plain_step_stay_within_budget(name, reference_encoding):
    run = _run(name)
    measured = CASES[name][2]
    total, mine = 0, Counter()
    for step in range(1, max(measured) + 1):
        with HostReads() as reads:
            run.iteration(step)
        if step in measured:
            total = max(total, reads.total)
            own = Counter({k: v for k, v in reads.counts.items() if k.startswith(OWN)})
            mine = max(mine, own, key=lambda c: c.total())
    assert mine.total() <= MINE[name], dict(mine)
    assert total <= BUDGETS[name], total


RESUMES = {  # expert -> (config changes, steps, the step the first part stops after)
    "ed3dgs": ({"random_until": 0, "multiview_ssim_iters": 3}, 8, 2),  # the kept frame of step 2
    "ex4dgs": ({}, 14, 10),  # mid-pass, after growths and conversions, with a conversion armed
}


def _resumable(name: str):
    if name == "mode":  # its warm-up counts from the step its base starts deforming
        from moegs.mode import MoDEConfig, MoDEExpert

        config = with_fields(
            MoDEConfig.from_preset("quick"),
            {"experts": ("ed3dgs", "fourdgs"), "warmup_iterations": 4, "train.iterations": 8},
        )
        torch.manual_seed(0)
        scene = tiny_scene()
        return MoDEExpert.from_scene(scene, config), scene, 3
    changes, steps, stop = RESUMES[name]
    expert, scene = _build(name, **{**changes, "train.iterations": steps})
    return expert, scene, stop


def _same(a, b) -> bool:
    """Equal state values: tensors bit for bit, dicts (extra state) key by key."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return a == b


@pytest.mark.parametrize("name", [*sorted(RESUMES), "mode"])
def test_the_host_schedule_state_resumes_exactly(name, tmp_path):
    """Checkpoint after ``stop`` steps, resume in a fresh expert: the same run as an uninterrupted one."""
    full, scene, stop = _resumable(name)
    train(full, scene, out_dir=tmp_path / "full", progress=False)
    part, _, _ = _resumable(name)
    train(part, scene, out_dir=tmp_path / "part", progress=False, stop_after=stop)
    resumed, _, _ = _resumable(name)
    fresh, saved = resumed.state_dict(), part.state_dict()
    extra = [k for k in fresh if k.endswith("_extra_state")]
    assert extra and not all(_same(saved[k], fresh[k]) for k in extra)  # a resume dropping it would differ
    result = train(resumed, scene, out_dir=tmp_path / "part", progress=False)
    assert result["resumed_from"] == stop and result["completed"]
    a, b = full.state_dict(), resumed.state_dict()
    assert a.keys() == b.keys()
    for key in a:
        assert _same(a[key], b[key]), key
    history = [read_checkpoint(tmp_path / run / CHECKPOINT_NAME)["history"] for run in ("full", "part")]
    assert history[0] == history[1]
