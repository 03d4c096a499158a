"""Procedural dynamic benchmark scenes rendered by an analytic ray caster, in native dataset layouts.

Each scene mixes the motion regimes the MoE-GS / MoDE thesis is about (different deformation models
win in different regions and times): a static textured background, a rigid object on a smooth path,
a fast articulated limb, a non-rigid pulsating blob, an object with abrupt irregular motion (sharp
turns and spin reversals), an object that appears and disappears, and an appearance change.

API::

    generate(name, out_dir, preset="quick", seed=0, **overrides) -> Path     # writes the layout
    load_synthetic(name, preset="quick", seed=0, root=None, **loader_kwargs) -> Scene
    load_ground_truth(scene_dir, view) -> GroundTruth                         # depth, ids, dynamic
    ground_truth(scene, view) -> GroundTruth                                  # for a loaded Scene
    render_ground_truth(name, camera, time=None, seed=0) -> Render            # any camera / time
    build_scene(name, seed) -> SceneDescription                               # the analytic scene

Named scenes: ``n3v_like`` (N3V layout: forward-facing rig, ``cam00`` held out, ``poses_bounds.npy``
+ lossless ``camXX.mp4``) and ``dnerf_like`` (D-NeRF layout: monocular orbit, one camera per time,
``transforms_{train,val,test}.json`` + RGBA PNGs). Presets ``quick`` and ``paper`` (``PRESETS``).
"""

from __future__ import annotations

from pathlib import Path

from torch import Tensor

from moegs.data._io import with_background
from moegs.data.scene import Scene
from moegs.data.synthetic.generate import generate, read_meta
from moegs.data.synthetic.groundtruth import (
    GroundTruth,
    ground_truth,
    gt_files,
    load_ground_truth,
    load_mask,
    load_regimes,
    render_ground_truth,
)
from moegs.data.synthetic.raycast import Primitive, Render, render
from moegs.data.synthetic.scenes import CATEGORIES, SCENES, SceneDescription, SceneObject, build_scene
from moegs.data.synthetic.spec import PRESETS, SyntheticSpec, get_spec, spec_hash

__all__ = [
    "CATEGORIES",
    "PRESETS",
    "SCENES",
    "GroundTruth",
    "Primitive",
    "Render",
    "SceneDescription",
    "SceneObject",
    "SyntheticSpec",
    "build_scene",
    "generate",
    "get_spec",
    "ground_truth",
    "list_synthetic",
    "load_ground_truth",
    "load_synthetic",
    "render",
    "render_ground_truth",
    "scene_dir",
    "spec_hash",
]


def list_synthetic() -> list[str]:
    """Names of the synthetic scenes."""
    return sorted(PRESETS)


def scene_dir(
    name: str,
    preset: str = "quick",
    seed: int = 0,
    root: str | Path | None = None,
    overrides: dict | None = None,
) -> Path:
    """Folder a generation lives in: ``<root>/<name>-<preset>-s<seed>[-<hash8>]`` (hash suffix only with
    overrides); ``root`` defaults to ``cache_root()/synthetic``."""
    from moegs.paths import cache_root

    base = Path(root) if root is not None else cache_root() / "synthetic"
    folder = f"{name}-{preset}-s{seed}"
    if overrides:
        folder += "-" + spec_hash(get_spec(name, preset, **overrides), seed)[:8]
    return base / folder


def load_synthetic(
    name: str,
    preset: str = "quick",
    seed: int = 0,
    root: str | Path | None = None,
    *,
    overrides: dict | None = None,
    progress: bool = True,
    background: str | Tensor | None = None,
    **loader_kwargs,
) -> Scene:
    """Generate (if needed) and load a synthetic scene through the REAL loader of its layout.

    Args:
        name: ``n3v_like`` | ``dnerf_like``.
        preset: ``quick`` | ``paper``.
        seed: scene seed (textures, abrupt path, rig jitter).
        root: parent folder of the generations (default ``cache_root()/synthetic``).
        overrides: ``SyntheticSpec`` field overrides (e.g. ``{"num_frames": 4}``).
        background: as ``load_scene``'s (D-NeRF layout: the RGBA images are composited on it).
        loader_kwargs: passed to ``load_n3v`` / ``load_dnerf`` (defaults here: native resolution, the
            whole frame window with ``duration = num_frames`` for n3v).
    Returns:
        the loader's ``Scene`` with ``name = "synthetic:<name>"``, ``stand_in`` set, the ground-truth
        dynamic mask as every view's ``load_mask`` (instead of the D-NeRF loader's object alpha), one
        mask per motion regime as its ``load_regions`` (``load_regimes``), and
        ``scene.meta["synthetic"]`` (folder, seed, preset, objects, ...).
    """
    overrides = dict(overrides or {})
    spec = get_spec(name, preset, **overrides)
    folder = generate(
        name, scene_dir(name, preset, seed, root, overrides), preset, seed, progress=progress, **overrides
    )
    if spec.layout == "n3v":
        from moegs.data.n3v import load_n3v

        kwargs = {
            "resolution_scale": 1.0,
            "frames": (0, spec.num_frames),
            "duration": spec.num_frames,
            "time_mode": "global",
            **loader_kwargs,
        }
        scene = with_background(load_n3v, folder, background, **kwargs)
    else:
        from moegs.data.dnerf import load_dnerf

        scene = with_background(load_dnerf, folder, background, **{"resolution_scale": 1.0, **loader_kwargs})
    return _decorate(scene, folder, name, spec)


def _decorate(scene: Scene, folder: Path, name: str, spec: SyntheticSpec) -> Scene:
    from functools import partial

    meta = read_meta(folder) or {}
    scene.name = f"synthetic:{name}"
    scene.stand_in = f"{spec.stand_in_for} (synthetic stand-in)"
    for view in [*scene.train, *scene.test]:  # the ground-truth dynamic mask replaces a loader's mask
        size = (view.camera.width, view.camera.height)
        view.load_mask = partial(load_mask, gt_files(folder, view.camera.name)[2], size)
        view.load_regions = partial(load_regimes, folder, view.camera.name, size)
    info = {
        "dir": str(folder),
        "name": name,
        "preset": meta.get("preset"),
        "seed": meta.get("seed"),
        "spec_hash": meta.get("spec_hash"),
        "objects": meta.get("objects"),
        "dynamic_ids": meta.get("dynamic_ids"),
        "stand_in_for": spec.stand_in_for,
        "mask": "ground-truth dynamic mask (first hit is a non-static object)",
        "regions": "one mask per motion regime (the category of the object hit first)",
    }
    if isinstance(getattr(scene, "meta", None), dict):
        scene.meta["synthetic"] = info
    return scene
