"""Training recipes: the one place that turns an expert, a scene and a preset into a run's config.

    >>> recipe = config_for("grid4d", "dnerf:mutant", "paper")
    >>> recipe.config.train.iterations, recipe.background, recipe.base
    (50000, 'black', 'paper-dnerf')
    >>> scene = load_scene("dnerf:mutant", **recipe.load_kwargs)   # composited on black, as Grid4D does

Resolution order (each step is recorded in :attr:`Recipe.steps` and in a run's ``config.json``):

1. **dataset preset**: the expert's preset for the scene's dataset
   (``ExpertConfig.DATASET_PRESETS``: Grid4D on N3V -> ``paper-n3v``, its ``arguments/neu3d/*.py``);
   datasets the original has no config for get the closest one, marked as an adaptation;
2. **scene overrides**: the values the original sets for this one scene
   (``ExpertConfig.SCENE_OVERRIDES``: Grid4D ``dnerf:lego`` -> grid lr x250 ...); rules tied to a real
   dataset's world frame are turned off elsewhere (``ExpertConfig.own_frame_fields``: STG's N3V z prune);
3. **preset reduction**: ``paper`` changes nothing; ``quick`` applies the expert's named CPU reductions
   (``ExpertConfig.quick_reductions``: fewer iterations, points, levels ...), and nothing else;
4. **user overrides**: dotted field names, e.g. ``{"train.iterations": 100, "strategy.densify_every": 50}``;
5. **background**: the colour the original trains and evaluates on for this dataset
   (``ExpertConfig.BACKGROUNDS``), which :attr:`Recipe.load_kwargs` passes to ``load_scene``.

Stand-in scenes (``synthetic:n3v_like``) take the recipe of the dataset they stand in for (their layout,
or ``dataset=`` when the harness uses one stand-in for several datasets).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from moegs.data import canonical_scene
from moegs.experts.base import DatasetPreset
from moegs.io.config import changed_fields, get_field, with_fields

PRESETS = ("paper", "quick")
"""Recipe presets: the original's protocol and its named CPU reduction."""
QUICK_LOADER_ARGS = {"points": "auto"}
"""Loader arguments the ``quick`` preset replaces: it starts from whichever initial cloud the scene folder
has, where ``paper`` asks for each original's own (a missing one is an error naming the file)."""


@dataclass(frozen=True)
class Recipe:
    """The resolved config of one run and how it was made.

    Attributes:
        expert: registry name.
        scene: ``<dataset>:<scene>`` name.
        dataset: the dataset whose recipe applies (a stand-in's stood-for dataset).
        preset: ``paper`` or ``quick``.
        base: the expert config preset of ``dataset`` (e.g. ``paper-n3v``).
        base_source: where the base preset's values come from (or why it is an adaptation).
        adapted: True when the original has no config for ``dataset``.
        scene_overrides: the original's per-scene values applied (dotted field -> value).
        frame_overrides: world-frame rules turned off because the scene is a stand-in or the preset was
            written for another dataset (dotted field -> value).
        reductions: the preset's named reductions applied (dotted field -> value; empty for ``paper``).
        overrides: the caller's overrides applied (dotted field -> value).
        background: ``"white"`` or ``"black"``, what the original trains and evaluates on.
        config: the full expert config.
    """

    expert: str
    scene: str
    dataset: str
    preset: str
    base: str
    base_source: str
    adapted: bool
    scene_overrides: dict[str, Any]
    frame_overrides: dict[str, Any]
    reductions: dict[str, Any]
    overrides: dict[str, Any]
    background: str
    config: Any = field(repr=False)
    loader_args: dict[str, Any] = field(default_factory=dict)

    @property
    def load_kwargs(self) -> dict[str, Any]:
        """``load_scene`` keyword arguments this run needs: the background, the training resolution
        (stand-ins are generated at their own preset's size: only a user's resolution applies to them) and
        the original's loader arguments (``loader_args``)."""
        return scene_load_kwargs(
            self.scene,
            self.background,
            self.config.train.resolution_scale,
            user_scale="train.resolution_scale" in self.overrides,
            loader_args=self.loader_args,
        )

    @property
    def steps(self) -> list[str]:
        """One line per resolution step, for logs and reports."""
        base = f"{self.dataset} preset {self.base!r} ({self.base_source})"
        out = [base + (" [adaptation]" if self.adapted else "")]
        for label, values in (
            ("scene overrides", self.scene_overrides),
            ("world-frame rules off", self.frame_overrides),
            (f"{self.preset} reductions", self.reductions),
            ("user overrides", self.overrides),
            ("loader arguments", self.loader_args),
        ):
            if values:
                out.append(f"{label}: " + ", ".join(f"{k}={v!r}" for k, v in values.items()))
        out.append(f"background: {self.background}")
        return out

    def provenance(self) -> dict[str, Any]:
        """JSON-ready record of how the config was made (written into a run's ``config.json``)."""
        return {
            "expert": self.expert,
            "scene": self.scene,
            "dataset": self.dataset,
            "preset": self.preset,
            "base": self.base,
            "base_source": self.base_source,
            "adapted": self.adapted,
            "scene_overrides": _jsonable(self.scene_overrides),
            "frame_overrides": _jsonable(self.frame_overrides),
            "reductions": _jsonable(self.reductions),
            "overrides": _jsonable(self.overrides),
            "background": self.background,
            "loader_args": _jsonable(self.loader_args),
        }


def scene_load_kwargs(
    scene: str,
    background: str | None,
    resolution_scale: float | None,
    user_scale: bool,
    loader_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``load_scene`` keyword arguments of a run: its ``background`` (if any), its training
    ``resolution_scale`` (if any), which a stand-in (generated at its own preset's size) takes only when
    the user set it (``user_scale``), and its recipe's ``loader_args`` (lists from a JSON record become
    tuples)."""
    kwargs: dict[str, Any] = {"background": background} if background else {}
    if resolution_scale is not None and (not scene.startswith("synthetic:") or user_scale):
        kwargs["resolution_scale"] = resolution_scale
    for name, value in (loader_args or {}).items():
        kwargs[name] = tuple(value) if isinstance(value, list) else value
    return kwargs


def _jsonable(values: Mapping[str, Any]) -> dict[str, Any]:
    from moegs.io.config import to_dict

    def convert(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return to_dict(v)
        return list(v) if isinstance(v, tuple) else v

    return {k: convert(v) for k, v in values.items()}


# -------------------------------------------------------------------------------------------- scenes
def override_key(scene: str, dataset: str | None = None) -> tuple[str, str]:
    """The dataset whose recipes apply to ``scene`` (default :func:`dataset_of`) and the key of the
    scene's overrides, ``<dataset>:<scene>`` in the suite's spelling (``n3v:flame_salmon_1`` ->
    ``n3v:flame_salmon``); a bare name (a scene built by hand) is used as it is."""
    dataset = dataset or dataset_of(scene)
    name = canonical_scene(scene).partition(":")[2] if ":" in scene else scene
    return dataset, f"{dataset}:{name}"


def dataset_of(scene: str) -> str:
    """The dataset whose recipes apply to a scene name: its prefix, or a stand-in's layout."""
    prefix, _, name = scene.partition(":")
    if not name:
        raise ValueError(f"scene must look like '<dataset>:<scene>', got {scene!r}")
    if prefix != "synthetic":
        return prefix
    from moegs.data.synthetic import PRESETS as SYNTHETIC

    if name not in SYNTHETIC:
        raise ValueError(f"unknown synthetic scene {name!r}; valid: {sorted(SYNTHETIC)}")
    return next(iter(SYNTHETIC[name].values())).layout


# ------------------------------------------------------------------------------------------- resolve
def config_for(
    expert: str,
    scene: str,
    preset: str = "paper",
    *,
    dataset: str | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Recipe:
    """The config a run of ``expert`` on ``scene`` uses at ``preset`` (see the module docstring).

    Args:
        expert: registry name (``moegs list``).
        scene: ``<dataset>:<scene>`` (``dnerf:mutant``, ``synthetic:n3v_like``).
        preset: ``paper`` (the original's protocol) or ``quick`` (its named CPU reduction).
        dataset: the dataset whose recipe applies; default: the scene's (a stand-in's layout).
        overrides: dotted field -> value, applied last (``{"train.iterations": 200}``).
    """
    from moegs.experts import get_expert_class

    if preset not in PRESETS:
        raise ValueError(f"unknown recipe preset {preset!r}; valid: {', '.join(PRESETS)}")
    cls = get_expert_class(expert).config_class
    dataset, key = override_key(scene, dataset)
    base = cls.dataset_preset(dataset)
    config = cls.from_preset(base.preset)
    scene_overrides = dict(cls.SCENE_OVERRIDES.get(key, {}))
    config = with_fields(config, scene_overrides)
    real = not scene.startswith("synthetic:")
    frame_overrides = dict(cls.own_frame_fields(config, dataset, real))
    config = with_fields(config, frame_overrides)
    reductions = dict(cls.quick_reductions(config)) if preset == "quick" else {}
    config = with_fields(config, reductions)
    user = dict(overrides or {})
    config = with_fields(config, user)
    loader_args = {**cls.LOADER_ARGS.get(dataset, {}), **cls.LOADER_ARGS.get(key, {})} if real else {}
    if preset == "quick":
        loader_args.update((k, v) for k, v in QUICK_LOADER_ARGS.items() if k in loader_args)
    return Recipe(
        expert=expert,
        scene=scene,
        dataset=dataset,
        preset=preset,
        base=base.preset,
        base_source=base.source,
        adapted=base.adapted,
        scene_overrides=scene_overrides,
        frame_overrides=frame_overrides,
        reductions=reductions,
        overrides=user,
        background=cls.background_for(dataset),
        config=config,
        loader_args=loader_args,
    )


__all__ = [
    "PRESETS",
    "DatasetPreset",
    "Recipe",
    "changed_fields",
    "config_for",
    "dataset_of",
    "get_field",
    "with_fields",
]
