"""STG with temporal segments (MoE-GS trains STG on N3V as two 150-frame models): one ``STGExpert`` per
frame window, trained with the shared loop, answered by ``STGSegments`` at global time."""

from __future__ import annotations

from pathlib import Path

import torch

from moegs.data.scene import Scene
from moegs.experts.stg import STGConfig, STGExpert, STGSegments, segment_bounds, segment_scene
from moegs.train.loop import train


def train_segments(
    scene: Scene, config: STGConfig, out_dir: str | Path | None = None, progress: bool = False
) -> tuple[STGSegments, list[dict]]:
    """Train one ``STGExpert`` per ``config.segment_frames`` window with the shared training loop.

    Returns the wrapper and each segment's ``moegs.train.loop.train`` result (``out_dir/segment_<k>``
    holds each run, so an interrupted call resumes).
    """
    bounds = segment_bounds(sorted({v.camera.time for v in scene.train}), config.segment_frames)
    models, results = [], []
    for k, (start, stop) in enumerate(bounds):
        part = segment_scene(scene, start, stop)
        torch.manual_seed(config.train.seed)  # network initialisation independent of what ran before
        model = STGExpert.from_scene(part, config)
        run_dir = Path(out_dir) / f"segment_{k}" if out_dir is not None else None
        results.append(train(model, part, out_dir=run_dir, progress=progress))
        models.append(model)
    return STGSegments(models, bounds).eval(), results
