"""Test-set model selection, as Grid4D's ``iteration_best``: at given steps the test views are scored and
the model whose PSNR is at least the best so far is kept (Grid4D ``train.py:136-142``, steps ``:266-267``).
Its README renders the last model by default and the best one on request (``--iteration best``), so a run
reports both: ``train()``'s ``test`` is the last model's, ``best`` the kept one's. This selects on the test
set; no other expert's protocol does.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from moegs.io import read_json, write_json

if TYPE_CHECKING:
    from moegs.data.scene import Scene
    from moegs.experts.base import Expert

BEST_NAME = "best.safetensors"
"""The kept model's checkpoint in a run folder."""
BEST_RECORD = "best.json"
"""``{"step", "psnr"}`` of the kept model."""


class BestModel:
    """The best-scoring model of a run so far: in ``folder`` (a checkpoint and its record; a resumed run
    keeps it if it is not newer than the step resumed from) or, without a folder, a copy in memory."""

    def __init__(self, steps: Iterable[int], folder: Path | None, resumed_from: int | None) -> None:
        self.steps = frozenset(steps)
        self.folder = folder
        self.step: int | None = None
        self.psnr = -math.inf
        self._copy: Expert | None = None
        record = folder / BEST_RECORD if folder is not None else None
        if record is not None and record.is_file():
            kept = read_json(record)
            if resumed_from is not None and kept["step"] <= resumed_from:
                self.step, self.psnr = int(kept["step"]), float(kept["psnr"])
            else:  # another run's, or past the step this run goes on from
                record.unlink()
                (folder / BEST_NAME).unlink(missing_ok=True)

    def offer(self, step: int, psnr: float, expert: Expert, save: Any) -> None:
        """Keep the model of ``step`` if its ``psnr`` is at least the best so far (``>=``, as Grid4D).
        ``save(path)`` writes the run's state (``TrainingRun.write``)."""
        if psnr < self.psnr:
            return
        self.step, self.psnr = step, psnr
        if self.folder is None:
            self._copy = copy.deepcopy(expert)
        else:
            save(self.folder / BEST_NAME)
            write_json(self.folder / BEST_RECORD, {"step": step, "psnr": psnr})

    def expert(self, scene: Scene, device: Any) -> Expert:
        """The kept model in eval mode (after an ``offer`` was kept)."""
        if self.folder is None:
            return self._copy.eval()
        from moegs.train.checkpoint import load_expert

        return load_expert(self.folder / BEST_NAME, scene, device=device)[0]
