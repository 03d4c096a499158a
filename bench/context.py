"""What a cell function gets: the workspace, the preset, the device, scene loading and artefacts (built on
demand).

Scenes are loaded on the CPU (``Context.scene``) and given so to the library, whose trainers and loaders
place what they need beside the model (``device=ctx.device``); the cells' own renders and scores use the
scene placed on the device (``Context.on_device``, ``moegs.data.scene.Scene.to``).

``Context.artifact(task)`` returns the folder of a built artefact; when it is not built yet (a table
run alone, or a dependency that another worker is still building) it builds it here under the
store's lock, recursively building what it depends on. Every artefact used is recorded with its
checkpoint hashes so the result JSON can name exactly what it was computed from.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from bench.cells import kind_module
from bench.presets import BenchPreset, get_preset
from bench.store import Workspace
from bench.tasks import Task


class Context:
    """Per-process services for cell functions."""

    def __init__(
        self, workspace: Workspace, preset: BenchPreset | str, progress: bool = False, device: Any = None
    ) -> None:
        from moegs.device import resolve_device

        self.workspace = workspace
        self.preset = get_preset(preset) if isinstance(preset, str) else preset
        self.progress = progress
        self.device = resolve_device(device or "cpu")
        """Where the cells compute (a ``torch.device``; the worker resolves the task's device kind)."""
        self.used: dict[str, dict[str, Any]] = {}
        self.task: Task | None = None
        """The task being run (set by the worker; cells write their files under its ``files_dir``)."""
        self._scenes: dict[str, Any] = {}
        self._origins: dict[int, tuple[Task, str | None]] = {}

    def log(self, message: str) -> None:
        print(f"[bench] {message}", file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ scenes
    def scene(self, task: Task, background: str | None = None, **changes: Any):
        """The ``moegs.Scene`` of ``task`` (loaded once per process), on ``background`` when given (the
        recipe's: D-NeRF composites its images on it); ``changes`` replace loader arguments."""
        from bench.keys import canonical_json
        from bench.scenes import load

        kwargs = {**task.scene_kwargs, **changes}
        if background is not None:
            kwargs["background"] = background
        key = task.scene + canonical_json(kwargs)
        if key not in self._scenes:
            self.log(f"loading scene {task.scene} {kwargs}")
            self._scenes[key] = load(task.scene, kwargs)
            self._origins[id(self._scenes[key])] = (task, background)
        return self._scenes[key]

    def on_device(self, scene: Any):
        """``scene`` placed on :attr:`device` (``Scene.to``; itself on the CPU): what the cells render and
        score on."""
        return scene if self.device.type == "cpu" else scene.to(self.device)

    def native_scene(self, scene: Any):
        """``scene`` (loaded by :meth:`scene`) at its native resolution, placed on :attr:`device`, when the
        preset scores upsampled renders (``BenchPreset.native_psnr``) and it is a real scene loaded
        smaller; else ``None``."""
        task, background = self._origins[id(scene)]
        if not self.preset.native_psnr or task.scene.startswith("synthetic:"):
            return None
        if task.scene_kwargs.get("resolution_scale", 1.0) >= 1.0:
            return None
        return self.on_device(self.scene(task, background, resolution_scale=1.0))

    def device_record(self) -> dict[str, Any]:
        """What a result or artefact records of the device: ``{"kind", "name", "gpu"}`` (``gpu``: the
        GPU's model, None on the CPU)."""
        from moegs.device import device_kind, device_name, gpu_model

        return {
            "kind": device_kind(self.device),
            "name": device_name(self.device),
            "gpu": gpu_model(self.device),
        }

    # ------------------------------------------------------------------ artefacts
    def artifact(self, task: Task) -> Path:
        """Folder of the built artefact ``task`` (building it and its dependencies if needed)."""
        if task.action != "build":
            raise ValueError(f"Context.artifact needs a build task, got {task}")
        module = kind_module(task.kind)
        for dep in getattr(module, "deps", lambda _t: [])(task):
            self.artifact(dep)
        if not self.workspace.is_built(task):
            self.log(f"building {task.slug} ({task.key})")
        folder = self.workspace.ensure(task, lambda out: self._build(module, task, out), warn=self.log)
        meta = self.workspace.artifact_meta(task)
        config_file = folder / "config.json"  # written by moegs.train.loop.train: expert + training config
        config = json.loads(config_file.read_text()) if config_file.is_file() else None
        self.used[task.key] = {
            "config": config,
            "kind": task.kind,
            "params": dict(task.params),
            "seed": task.seed,
            "files": meta.get("files", {}),
            "build_seconds": meta.get("build_seconds"),
            "train_seconds": meta.get("train_seconds"),
            "device": meta.get("device"),
        }
        return folder

    def _build(self, module: Any, task: Task, out: Path) -> dict[str, Any]:
        """Build ``task`` into ``out``; its meta with the device it ran on."""
        return {**(module.build(task, self, out) or {}), "device": self.device_record()}

    def meta(self, task: Task) -> dict[str, Any]:
        """``artifact.json`` of a built artefact (building it if needed)."""
        self.artifact(task)
        return self.workspace.artifact_meta(task)
