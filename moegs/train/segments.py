"""STG with temporal segments: one ``STGExpert`` per window of ``STGConfig.segment_frames`` frames (STG: 50,
``configs/n3d_full/*.json:7``, ``:8`` in coffee_martini and flame_salmon_1; MoE-GS's STG†: 150), trained with
the shared loop and answered at global time by ``STGSegments``.

A segmented run folder holds ``segment_<k>/`` (each an ordinary run folder: checkpoint, config, metrics),
``segments.json`` (the normalised-time bounds), and the whole scene's ``config.json`` and ``metrics.json``
(the wrapper scored on the scene's test views), so reuse, resumption and ``load_segments`` treat it as one
run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from moegs.data.scene import Scene
from moegs.device import resolve_device
from moegs.experts.stg import STGConfig, STGExpert, STGSegments, segment_bounds, segment_scene
from moegs.io import read_json, write_json
from moegs.train.checkpoint import load_expert
from moegs.train.evaluate import eval_views, evaluate
from moegs.train.loop import train, write_run_config

SEGMENTS_NAME = "segments.json"


def scene_segments(scene: Scene, config: Any) -> list[tuple[float, float]]:
    """The ``(start, stop)`` windows ``config`` splits ``scene``'s training frames into; one window for an
    expert without segments (any config but an ``STGConfig`` with ``segment_frames``)."""
    frames = config.segment_frames if isinstance(config, STGConfig) else None
    return segment_bounds(sorted({v.camera.time for v in scene.train}), frames)


def train_segments(
    scene: Scene,
    config: STGConfig,
    out_dir: str | Path | None = None,
    recipe: dict[str, Any] | None = None,
    device: torch.device | str | None = None,
    **kwargs: Any,
) -> tuple[STGSegments, dict[str, Any]]:
    """Train one ``STGExpert`` per segment of ``scene`` (``scene_segments``) into ``out_dir/segment_<k>``
    (an interrupted call resumes) on ``device`` (None: the CPU); ``kwargs`` go to
    ``moegs.train.loop.train``. A segment that stops early (``stop_after``) ends the call there.

    Returns:
        the wrapper (eval mode) and the whole run's result: the loop's keys summed or averaged over the
        segments (``step``, ``iterations``, ``train_seconds`` summed; ``seconds_per_step``, ``final_loss``
        their mean), ``test`` scored with the wrapper on the scene's test views, and ``segments`` (each
        segment's own result).
    """
    bounds = scene_segments(scene, config)
    device = resolve_device(device or "cpu")
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        write_run_config(out, STGExpert.name, scene, config, config.train, recipe, device)
        write_json(out / SEGMENTS_NAME, {"expert": STGExpert.name, "bounds": [list(b) for b in bounds]})
    models, results = [], []
    for k, (start, stop) in enumerate(bounds):
        part = segment_scene(scene, start, stop)
        torch.manual_seed(config.train.seed)  # network initialisation independent of what ran before
        model = STGExpert.from_scene(part, config).to(device)
        run_dir = out / f"segment_{k}" if out is not None else None
        results.append(train(model, part, out_dir=run_dir, recipe=recipe, **kwargs))
        models.append(model)
        if not results[-1]["completed"]:
            break
    segments = STGSegments(models, bounds[: len(models)]).eval()
    result = _whole_run(segments, scene, config, results, planned=len(bounds))
    if out is not None:
        write_json(out / "metrics.json", result)
    return segments, result


def _whole_run(
    segments: STGSegments, scene: Scene, config: STGConfig, results: list[dict[str, Any]], planned: int
) -> dict[str, Any]:
    """The loop's result keys for the whole segmented run of ``planned`` segments (see ``train_segments``)."""
    completed = len(results) == planned and all(r["completed"] for r in results)
    scene = scene.to(next(segments.parameters()).device)
    test_views = eval_views(scene.test, config.train.max_eval_views)
    test = None
    if completed and test_views:
        test = evaluate(
            segments, test_views, scene.background, config.train.metric_profile, config.train.backend
        )

    def mean(key: str) -> float | None:
        values = [r[key] for r in results if r[key] is not None]
        return sum(values) / len(values) if values else None

    return {
        "expert": STGExpert.name,
        "scene": scene.name,
        "stand_in": scene.stand_in,
        "completed": completed,
        "step": sum(r["step"] for r in results),
        "iterations": config.train.iterations * planned,
        "num_gaussians": segments.num_gaussians,
        "train_seconds": sum(r["train_seconds"] for r in results),
        "seconds_per_step": mean("seconds_per_step"),
        "final_loss": mean("final_loss"),
        "resumed_from": [r["resumed_from"] for r in results],
        "test": test,
        "evaluations": [],
        "segments": results,
    }


def load_segments(
    out_dir: str | Path, scene: Scene, expect: str | None = None, device: torch.device | str | None = None
) -> tuple[STGSegments, dict[str, Any]]:
    """Rebuild the trained ``STGSegments`` of a segmented run folder for ``scene``: each segment's model on
    its window of the scene, on ``device`` (None: the CPU). Refuses unless ``expect`` (if given) and
    ``segments.json``'s ``expert`` name STG. Returns the wrapper (eval mode) and ``{"segments":
    [checkpoint state]}``."""
    out = Path(out_dir)
    record = read_json(out / SEGMENTS_NAME, "segmented run record")
    if record.get("expert") != STGExpert.name:
        raise ValueError(
            f"{out / SEGMENTS_NAME}: expected 'expert': {STGExpert.name!r} (the only expert trained in "
            f"segments), got {record.get('expert')!r}"
        )
    if expect is not None and expect != STGExpert.name:
        raise ValueError(f"{out} holds a segmented {STGExpert.name!r} run, but its run says {expect!r}")
    bounds = [tuple(map(float, b)) for b in record.get("bounds", [])]
    if not bounds or any(len(b) != 2 for b in bounds):
        raise ValueError(f"{out / SEGMENTS_NAME}: expected 'bounds' as a list of [start, stop] pairs")
    models, states = [], []
    for k, (start, stop) in enumerate(bounds):
        model, state = load_expert(
            out / f"segment_{k}", segment_scene(scene, start, stop), expect=STGExpert.name, device=device
        )
        models.append(model)
        states.append(state)
    return STGSegments(models, bounds).eval(), {"segments": states}
