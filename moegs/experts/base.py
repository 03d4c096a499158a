"""The ``Expert`` contract shared by every dynamic/static Gaussian method.

An expert owns

* ``splats``: a ``ParameterDict`` of *per-Gaussian* tensors, all with leading dimension ``N``
  (canonical means, log-scales, raw quaternions, opacity logits, SH, and any per-Gaussian extras
  such as STG polynomial coefficients or E-D3DGS embeddings). Densification strategies clone,
  split, prune and relocate exactly these, keeping optimiser state in step.
* ``fields``: an ``nn.Module`` holding everything that is not per-Gaussian (MLPs, hash grids,
  hexplanes, temporal embeddings, decoders).

and answers ``frame(t, camera)`` with the activated ``GaussianFrame`` at normalised time ``t``.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Self

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.gaussians import GaussianFrame
from moegs.io.config import Presets, with_fields
from moegs.train.config import TrainConfig
from moegs.train.params import ParamGroup
from moegs.train.strategy.base import NEVER

if TYPE_CHECKING:
    from moegs.data.scene import Scene, View
    from moegs.render import RenderOutput
    from moegs.train.strategy.base import Strategy


def splat_param_groups(
    splats: nn.ParameterDict,
    config: ExpertConfig,
    spatial_lr_scale: float,
    constant: list[tuple[str, float]],
    **options,
) -> list[ParamGroup]:
    """The 3DGS optimiser layout over per-Gaussian tensors: ``means`` on the config's exponential
    schedule (``means_lr`` -> ``means_lr_final`` over ``means_lr_max_steps``, both rates times
    ``spatial_lr_scale``), each ``(key, lr)`` of ``constant`` at a constant rate; ``options`` (``eps``,
    ``optimizer``) apply to every group."""
    c, s = config, spatial_lr_scale
    first = ParamGroup(
        "means",
        [splats["means"]],
        c.means_lr * s,
        lr_final=c.means_lr_final * s,
        max_steps=c.means_lr_max_steps,
        **options,
    )
    return [first] + [ParamGroup(key, [splats[key]], rate, **options) for key, rate in constant]


# quick presets: the static baseline's 30k -> 600 (50x shorter), shared by every expert
QUICK_ITERATIONS = 600
QUICK_RESOLUTION = 0.125  # D-NeRF 800x800 -> 100x100, so a run takes about a minute on 2 cores


def quick_step(step: int, iterations: int) -> int:
    """Iteration ``step`` of an ``iterations``-long schedule moved to the same fraction of the quick run
    (``NEVER`` stays never)."""
    return step if step >= NEVER else round(step * QUICK_ITERATIONS / iterations)


def quick_sh_interval(paper: ExpertConfig) -> int:
    """The recipe's SH-band interval moved to the same fraction of the quick run (3DGS: one band per 1000
    of 30k iterations -> per 20 of 600), so every band trains as long, relative to the run, as in the
    original. Measured: 4DGaussians stretched to 3000 iterations on the N3V stand-in with the unscaled
    1000 switched band 3 on at the last step, a colour cast on every view (25.0 dB full, 23.7 dynamic);
    scaled, 33.3 and 28.1 dB (no SH at all: 32.7 and 27.1)."""
    return max(1, quick_step(paper.train.sh_degree_interval, paper.train.iterations))


@dataclass(frozen=True)
class DatasetPreset:
    """Which preset of an expert config a dataset uses, and where its values come from.

    Attributes:
        preset: a name of ``ExpertConfig.presets()``.
        source: the original's config files (``"arguments/neu3d/*.py"``), or why it is an adaptation.
        adapted: True when the original has no config for the dataset.
    """

    preset: str
    source: str
    adapted: bool = False


NEAR_3DGS = 0.2
"""The 3DGS CUDA rasterizer culls a Gaussian whose view-space depth is ``<= 0.2`` (graphdeco-inria
``diff-gaussian-rasterization``, ``cuda_rasterizer/auxiliary.h:154``, ``in_frustum``), in scene units and
for every dataset; the projection matrix's ``znear`` 0.01 culls nothing. The forks that 3DGS-MCMC,
DeformableGS, 4DGaussians, Grid4D, E-D3DGS and STG train and evaluate with keep it (``auxiliary.h:154``;
STG's ``forward_full`` line 157), as does the stock rasterizer the MoE-GS code splats routing weights with;
Ex4DGS's takes the dataset's near, 0.2 by default (``Ex4DGSConfig.near``). gsplat culls at
``near_plane``, 0.01 by default."""


def clip_camera(camera: Camera, near: float | None, far: float | None = None) -> Camera:
    """``camera`` with its near plane raised to ``near`` and its far plane lowered to ``far`` (each
    unchanged when None or already tighter)."""
    if near is not None and near > camera.near:
        camera = replace(camera, near=near)
    if far is not None and far < camera.far:
        camera = replace(camera, far=far)
    return camera


@dataclass
class ExpertConfig(Presets):
    """Base of expert configs: the training settings, named presets and the recipe tables.

    Subclasses add their fields (each with a docstring; constants that differ from the paper or the
    original code say where they come from), write a ``paper_<dataset>`` classmethod per dataset config
    of the original (see ``presets``), implement ``quick_fields``, and fill the
    recipe tables that ``moegs.recipes.config_for`` reads:

    * ``DATASET_PRESETS``: dataset -> the preset holding the original's config for it (``"*"``: one
      recipe for every dataset); other datasets use ``DEFAULT_PRESET``, marked as an adaptation;
    * ``SCENE_OVERRIDES``: ``"<dataset>:<scene>"`` -> dotted field -> the value the original sets for
      that scene (each with the original's file and line);
    * ``BACKGROUNDS``: dataset -> ``"white"`` / ``"black"`` the original trains and evaluates on
      (``"*"``: every other dataset).
    """

    train: TrainConfig = field(default_factory=TrainConfig)
    """Settings of the training loop (iterations, batch, D-SSIM weight, resolution ...)."""
    near: float | None = NEAR_3DGS
    """View depth at or below which the original's rasterizer drops a Gaussian (radius 0) in training and
    evaluation renders; renders use the larger of this and the camera's own near plane (None: the
    camera's). Default: the 3DGS rasterizer that every expert but Ex4DGS is built on (``NEAR_3DGS``)."""

    DATASET_PRESETS: ClassVar[dict[str, DatasetPreset]] = {}
    DEFAULT_PRESET: ClassVar[str] = "paper"
    SCENE_OVERRIDES: ClassVar[dict[str, dict[str, Any]]] = {}
    BACKGROUNDS: ClassVar[dict[str, str]] = {"*": "black"}
    LOADER_ARGS: ClassVar[dict[str, dict[str, Any]]] = {}
    """``load_scene`` arguments the original trains a real scene with, by dataset (``"n3v"``) or scene
    (``"n3v:coffee_martini"``, which wins): excluded cameras, the resize filter, the initial cloud
    (``moegs.recipes`` passes them as ``Recipe.loader_args``; ``quick`` reads whichever cloud the folder
    has, ``QUICK_LOADER_ARGS``; stand-ins are generated, so they take none)."""

    DEFAULT_DATASET: ClassVar[str | None] = None
    """The dataset whose original config the field defaults are (its ``paper-<dataset>`` preset is the
    class itself); None when the defaults are the original's code defaults only."""

    @classmethod
    def presets(cls) -> dict[str, Callable[[], Self]]:
        """``paper`` (the field defaults), ``paper-<dataset>`` for ``DEFAULT_DATASET`` and for each
        ``paper_<dataset>`` classmethod, and ``quick``."""
        out: dict[str, Callable[[], Self]] = {"paper": cls}
        if cls.DEFAULT_DATASET is not None:
            out[f"paper-{cls.DEFAULT_DATASET}"] = cls
        for attr in dir(cls):
            if attr.startswith("paper_"):
                out[f"paper-{attr.removeprefix('paper_')}"] = getattr(cls, attr)
        out["quick"] = cls.quick
        return out

    @classmethod
    def dataset_preset(cls, dataset: str) -> DatasetPreset:
        """The preset of ``dataset`` (an adaptation of ``DEFAULT_PRESET`` when the original has none)."""
        for key in (dataset, "*"):
            if key in cls.DATASET_PRESETS:
                return cls.DATASET_PRESETS[key]
        known = ", ".join(sorted(cls.DATASET_PRESETS)) or "none"
        return DatasetPreset(
            cls.DEFAULT_PRESET,
            f"adaptation: the original has no {dataset} config (configs: {known}); "
            f"its {cls.DEFAULT_PRESET!r} recipe is used",
            adapted=True,
        )

    @classmethod
    def background_for(cls, dataset: str) -> str:
        """``"white"`` or ``"black"``: the background the original uses on ``dataset``."""
        return cls.BACKGROUNDS.get(dataset, cls.BACKGROUNDS["*"])

    @classmethod
    def own_frame_fields(cls, config: Self, dataset: str, real: bool) -> dict[str, Any]:
        """Fields to reset where a preset's world-frame rule does not hold (dotted field -> value): rules
        tied to a dataset's coordinates (STG's N3V z < 4.5 prune, Ex4DGS's N3V near plane) are turned off
        on stand-ins and on datasets the preset was not written for. Default: none."""
        return {}

    @classmethod
    def quick_fields(cls, paper: Self) -> dict[str, Any]:
        """The expert's own named reductions of a ``paper`` config for the ``quick`` preset (dotted field ->
        value); ``quick_reductions`` adds the rules every expert shares."""
        raise NotImplementedError(f"{cls.__name__} defines no quick reductions")

    @classmethod
    def quick_reductions(cls, paper: Self) -> dict[str, Any]:
        """Every field in which ``quick`` differs from ``paper``: what every expert shares
        (``QUICK_ITERATIONS`` steps at ``QUICK_RESOLUTION``, the SH-band interval at the same fraction of
        the run) and the expert's own ``quick_fields``."""
        shared = {"train.iterations": QUICK_ITERATIONS, "train.resolution_scale": QUICK_RESOLUTION}
        return {**shared, **cls.quick_fields(paper), "train.sh_degree_interval": quick_sh_interval(paper)}

    @classmethod
    def quick(cls) -> Self:
        """The ``quick`` reduction of the default ``paper`` config."""
        paper = cls()
        return with_fields(paper, cls.quick_reductions(paper))


@dataclass
class SplatInputs:
    """One expert's rasterizer inputs for one view (see ``Expert.splat_inputs``).

    Attributes:
        frame: the activated Gaussians at the view's time (``C`` channels after SH evaluation).
        background: ``[C]`` in the frame's channels, or None (black).
        antialiased: the 0.1-px dilation mode with opacity compensation (Ex4DGS).
        decode: splatted ``[H, W, C]`` -> RGB ``[H, W, 3]`` for this view; None = identity.
        near: the expert's near plane (``ExpertConfig.near``): the render's camera is ``clip_camera``-ed.
        far: the expert's far plane, None for the camera's (only Ex4DGS has one, ``Ex4DGSConfig.far``).
    """

    frame: GaussianFrame
    background: Tensor | None
    antialiased: bool = False
    decode: Callable[[Tensor], Tensor] | None = None
    near: float | None = None
    far: float | None = None

    def decoded(self, image: Tensor) -> Tensor:
        return image if self.decode is None else self.decode(image)


def render_splat_inputs(
    inputs: SplatInputs, camera: Camera, backend: str = "auto", return_stats: bool = False
) -> tuple[Tensor, RenderOutput, GaussianFrame]:
    """``(rgb [H, W, 3], RenderOutput, frame)``: rasterize ``inputs`` for ``camera`` (clipped to
    ``inputs.near`` / ``inputs.far``) and decode."""
    from moegs.render import rasterize

    out = rasterize(
        inputs.frame,
        clip_camera(camera, inputs.near, inputs.far),
        background=inputs.background,
        antialiased=inputs.antialiased,
        return_stats=return_stats,
        backend=backend,
    )
    return inputs.decoded(out.image), out, inputs.frame


def splat_inputs_bytes(inputs: SplatInputs) -> int:
    """Memory held by the tensors of ``inputs`` (its frame and background)."""
    f = inputs.frame
    tensors = [f.means, f.quats, f.scales, f.opacities, f.colors, f.sh, inputs.background]
    return sum(t.numel() * t.element_size() for t in tensors if t is not None)


def check_keep(keep: Tensor, num_gaussians: int) -> None:
    """``keep`` must be a bool mask over ``num_gaussians`` rows."""
    if keep.dtype != torch.bool or keep.shape != (num_gaussians,):
        raise ValueError(
            f"keep must be a bool tensor of shape [{num_gaussians}], got {keep.dtype} {list(keep.shape)}"
        )


class Expert(nn.Module, metaclass=abc.ABCMeta):
    """Base class for experts. Subclasses set ``name`` and ``config_class`` and implement
    ``from_scene``, ``frame`` and ``param_groups``.

    Attributes:
        name: registry name (e.g. ``"deformable"``).
        splats: per-Gaussian parameters (leading dim ``N``).
        fields: non-per-Gaussian modules.
        config: the expert's config dataclass (with ``quick`` / ``paper`` presets).
    """

    name: ClassVar[str] = ""
    config_class: ClassVar[type[ExpertConfig]]
    """The config dataclass (an ``ExpertConfig``)."""

    def __init__(
        self, config: ExpertConfig, splats: nn.ParameterDict, fields: nn.Module | None = None
    ) -> None:
        super().__init__()
        self.config = config
        self.splats = splats
        self.fields = fields if fields is not None else nn.Module()

    @classmethod
    @abc.abstractmethod
    def from_scene(cls, scene: Scene, config: ExpertConfig) -> Expert:
        """A freshly initialised expert for ``scene`` (points, extent, time range)."""

    @property
    def num_gaussians(self) -> int:
        return next(iter(self.splats.values())).shape[0]

    @abc.abstractmethod
    def frame(self, t: float, camera: Camera | None = None) -> GaussianFrame:
        """Activated Gaussians at normalised time ``t`` (``camera`` for view-dependent experts)."""

    def decode(self, features: Tensor, camera: Camera) -> Tensor:
        """Turn a splatted image ``[H, W, C]`` into RGB ``[H, W, 3]`` (identity except STG)."""
        return features

    def splat_inputs(self, camera: Camera, background: Tensor | None) -> SplatInputs:
        """What ``render`` rasterizes at ``camera.time`` (evaluation path): the frame, the background in
        the frame's channels, the rasterizer mode and the decoder. MoE-GS splats routing weights with
        exactly this geometry and renders several experts in one pass from it."""
        return SplatInputs(self.frame(camera.time, camera), background, near=self.config.near)

    def splat_inputs_key(self, camera: Camera) -> Hashable:
        """Equal keys promise equal ``splat_inputs`` in eval mode (for one background), so a frozen expert's
        inputs can be computed once per key (MoE-GS router training). Default: the camera (intrinsics,
        pose, size) and its time; experts whose inputs depend on the camera only through its time return
        the time."""
        return (camera.pose_key(), camera.time)

    def render(
        self, camera: Camera, background: Tensor | None, backend: str = "auto", return_stats: bool = False
    ) -> tuple[Tensor, RenderOutput, GaussianFrame]:
        """``(rgb [H, W, 3], RenderOutput, frame)`` at ``camera.time``, with gradients; used for training
        and evaluation. Default: ``rasterize(splat_inputs)`` then decode. Experts override
        ``splat_inputs`` for their rasterizer mode or background (Ex4DGS antialiasing, STG features) and
        ``render`` only for training-time extras."""
        return render_splat_inputs(self.splat_inputs(camera, background), camera, backend, return_stats)

    def frame_rows(self, t: float) -> Tensor | None:
        """Indices ``[len(frame(t))]`` of the per-Gaussian rows (``0 .. num_gaussians - 1``) that make up
        ``frame(t)``, in order; None when ``frame(t)`` holds every row in row order (the default).
        Per-Gaussian data attached from outside (MoE-GS routing weights) is indexed with it."""
        return None

    def keep_gaussians(self, keep: Tensor) -> None:
        """Drop the per-Gaussian rows where ``keep [num_gaussians]`` (bool) is False, in place (pruning a
        trained, frozen expert; optimiser state is not kept)."""
        check_keep(keep, self.num_gaussians)
        for key, value in list(self.splats.items()):
            self.splats[key] = nn.Parameter(value.detach()[keep].clone(), requires_grad=value.requires_grad)

    @abc.abstractmethod
    def param_groups(self) -> list[ParamGroup]:
        """Optimiser groups with each method's learning rates and schedules."""

    def regularization(self, step: int, frame: GaussianFrame | None = None) -> Tensor:
        """The method's own regularisers added to the photometric loss (zero by default)."""
        return torch.zeros((), device=next(self.parameters()).device)

    def on_step(self, step: int) -> bool:
        """Hook called before each training step (1-based iteration; stage switches, SH degree ...).

        Return True when a new stage starts and ``param_groups()`` changed: the loop then builds fresh
        optimisers from it (as 4DGaussians does between its coarse and fine stages).
        """
        return False

    def strategy(self) -> Strategy | None:
        """The densification strategy acting on ``splats`` (None: the set of Gaussians is fixed)."""
        return None

    def strategy_inputs(self, scene: Scene) -> dict:
        """Facts about the scene and the initial model that the strategy needs, computed once before the
        first step and added to its state (e.g. STG's per-camera far depth); default: none."""
        return {}

    def select_views(
        self, step: int, views: list[View], batch_size: int, generator: torch.Generator
    ) -> list[int] | None:
        """Indices into ``views`` (the training views) to train on at ``step``, or None for the loop's
        shuffled sampler. ``generator`` is the sampler's own, checkpointed generator (E-D3DGS camera and
        error-guided sampling, STG same-time view pairs, Ex4DGS progressive frames)."""
        return None

    def on_views(self, left: int) -> None:
        """Called with the views the loop's sampler held before drawing this step's batch (its stack, which
        shrinks through an epoch; ``ViewSampler.left``); default: nothing. Not called when
        ``select_views`` picks the views."""

    def observe(self, step: int, view: View, rgb: Tensor, target: Tensor, out: RenderOutput) -> Tensor | None:
        """Called after each training view's loss, before ``backward``: an extra loss term for that view
        (or None); experts also record per-view errors here (default: nothing)."""
        return None

    def view_groups(self, views: list[View]) -> list[int] | None:
        """Group index of each training view, or None for one group.

        Each training step draws ``TrainConfig.batch_size`` views from every group, so a batch of
        independent fits (e.g. one model per frame) sees all of its members every step.
        """
        return None
