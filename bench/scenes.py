"""Concrete scenes for a dataset and preset: the real folder when present, else a synthetic stand-in.

Rule (the same for every preset): the dataset's real scenes found under ``MOEGS_DATA`` are used, at
most ``preset.max_real_scenes`` of them in paper order; when none is present, one synthetic stand-in
scene in the dataset's native layout is used and every output says so. Checking for real data
imports ``moegs`` (and so torch); listing specs does not.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.datasets import get_dataset
from bench.presets import BenchPreset
from bench.results import write_text_atomic


@dataclass(frozen=True)
class SceneRef:
    """A scene a cell runs on.

    Attributes:
        name: ``moegs.data.load_scene`` name (``dnerf:mutant``, ``synthetic:n3v_like``).
        dataset: the paper dataset it stands for (``bench.datasets`` name).
        column: the paper's printed column for a real scene; ``None`` for a stand-in.
        real: True for real data.
    """

    name: str
    dataset: str
    column: str | None
    real: bool

    @property
    def label(self) -> str:
        if self.real:
            return self.name
        return f"{self.name} (synthetic stand-in for {get_dataset(self.dataset).title})"


def real_scene_path(dataset: str, scene: str) -> Path | None:
    """The real scene folder, or ``None`` when it is not present under the data root."""
    from moegs.data import resolve_scene_path

    try:
        return resolve_scene_path(f"{dataset}:{scene}")
    except (FileNotFoundError, ValueError):
        return None


def resolve_scenes(dataset: str, preset: BenchPreset, only: tuple[str, ...] = ()) -> list[SceneRef]:
    """Scenes of ``dataset`` to run under ``preset`` (``only``: restrict to these loader names)."""
    ds = get_dataset(dataset)
    wanted = [s for s in ds.scene_names() if not only or s in only]
    present = [s for s in wanted if real_scene_path(dataset, s) is not None]
    if preset.max_real_scenes is not None:
        present = present[: preset.max_real_scenes]
    if present:
        return [SceneRef(f"{dataset}:{s}", dataset, ds.column_of(s), True) for s in present]
    return [SceneRef(f"synthetic:{ds.stand_in}", dataset, None, False)]


def load_kwargs(ref: SceneRef, preset: BenchPreset) -> dict[str, Any]:
    """Keyword arguments of ``moegs.data.load_scene`` for ``ref`` under ``preset`` (JSON-serialisable)."""
    if not ref.real:
        kwargs: dict[str, Any] = {"preset": preset.synthetic_preset, "seed": 0}
        if preset.synthetic_overrides:
            kwargs["overrides"] = dict(preset.synthetic_overrides)
        return kwargs
    kwargs = dict(get_dataset(ref.dataset).paper_protocol)
    kwargs.update(preset.real_kwargs(ref.dataset))
    return {k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items()}


def load(name: str, kwargs: dict[str, Any]):
    """Load a scene (``moegs.Scene``); tuples that JSON turned into lists are restored."""
    from moegs.data import load_scene

    fixed = {k: tuple(v) if isinstance(v, list) else v for k, v in kwargs.items()}
    if name.startswith("synthetic:"):
        fixed.setdefault("progress", False)
    return load_scene(name, **fixed)


# ------------------------------------------------------------------------------------- input hashes
def _signature(folder: Path) -> str:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    h = hashlib.sha256()
    for p in files:
        st = p.stat()
        h.update(f"{p.relative_to(folder)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def folder_hash(folder: Path, cache_file: Path | None = None) -> str:
    """SHA-256 over every file's relative path and content, cached by (path, sizes, mtimes)."""
    folder = folder.resolve()
    sig = _signature(folder)
    cache: dict[str, Any] = {}
    if cache_file is not None and cache_file.is_file():
        try:
            cache = json.loads(cache_file.read_text())
        except json.JSONDecodeError:
            cache = {}
        hit = cache.get(str(folder))
        if hit and hit.get("signature") == sig:
            return hit["sha256"]
    h = hashlib.sha256()
    for p in sorted(q for q in folder.rglob("*") if q.is_file()):
        h.update(str(p.relative_to(folder)).encode() + b"\0")
        with open(p, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    digest = h.hexdigest()
    if cache_file is not None:
        cache[str(folder)] = {"signature": sig, "sha256": digest}
        write_text_atomic(cache_file, json.dumps(cache, indent=1))
    return digest


def scene_input_hash(name: str, kwargs: dict[str, Any], cache_file: Path | None = None) -> dict[str, str]:
    """What a result records about its scene's inputs: a content hash of the real folder, or of the
    synthetic generator's spec (name, preset, overrides, seed)."""
    dataset, scene = name.split(":", 1)
    if dataset == "synthetic":
        from moegs.data.synthetic import get_spec, spec_hash

        spec = get_spec(scene, kwargs.get("preset", "quick"), **kwargs.get("overrides", {}))
        return {"kind": "synthetic-spec", "sha256": spec_hash(spec, kwargs.get("seed", 0))}
    path = real_scene_path(dataset, scene)
    if path is None:
        raise FileNotFoundError(f"scene {name} disappeared from the data root")
    return {"kind": "folder", "path": str(path), "sha256": folder_hash(path, cache_file)}
