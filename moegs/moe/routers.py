"""MoE-GS routers: how ``K`` frozen experts' renders become one image.

* ``VolumeAwarePixelRouter`` (the paper's): per-Gaussian weights ``[w, w_dir, t * w_time]`` splatted
  with each expert's frozen geometry and opacity at time t; ``R'_k(u) = w2D_k(u) + Phi(w2D_dir_k(u),
  w2D_time_k(u), r(u))``; ``G'(u) = softmax_k R'(u)``; ``I(u) = sum_k G'_k(u) I_k(u)``.
* ``PixelRouter`` (ablation): image-space only, an MLP on the experts' colours, the ray and time.
* ``VolumeRouter`` (ablation): a per-Gaussian gate ``sigmoid(w + t * w_time)`` multiplies opacity before
  rasterization and every expert's Gaussians are rendered together in one image.

Every router returns a ``MoERender`` with convex per-pixel gates ``[K, H, W]``; ``inputs`` (each expert's
``splat_inputs`` for the camera) may be passed in when the caller keeps them (frozen experts).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.experts.base import Expert
from moegs.gaussians import cat
from moegs.moe.config import RouterConfig
from moegs.moe.splat import depth_culled, expert_inputs, ray_features, splat_experts
from moegs.render import frame_colors, rasterize


@dataclass
class MoERender:
    """One MoE-GS view.

    Attributes:
        image: the routed image ``[H, W, 3]``.
        gates: per-pixel expert weights ``[K, H, W]``, a convex combination at every pixel.
        expert_images: each expert's own render ``[K, H, W, 3]`` (no gradient).
        logits: router logits ``[K, H, W]`` before the softmax (None for the volume router).
        passes: rasterizer calls made for this view.
    """

    image: Tensor
    gates: Tensor
    expert_images: Tensor
    logits: Tensor | None
    passes: int


def experts_device(experts: Sequence[Expert]) -> torch.device:
    """Where the experts' Gaussians are: the device of the MoE model and its router."""
    return next(iter(experts[0].splats.values())).device


class GaussianWeights(nn.Module):
    """Per-Gaussian routing parameters of each expert: ``mix[k] [N_k, M]`` (base weights, the fast
    learning rate) and ``time[k] [N_k, 1]`` (w_time, the slow one).

    Rows follow the expert's per-Gaussian rows; ``rows(k, expert, t)`` picks those of ``frame(t)``.
    """

    def __init__(self, experts: Sequence[Expert], init_mix: Sequence[float], init_time: float) -> None:
        super().__init__()
        device = experts_device(experts)
        mix = torch.tensor([float(v) for v in init_mix], device=device)
        self.mix = nn.ParameterList([nn.Parameter(mix.repeat(e.num_gaussians, 1)) for e in experts])
        self.time = nn.ParameterList(
            [nn.Parameter(torch.full((e.num_gaussians, 1), init_time, device=device)) for e in experts]
        )

    def rows(self, k: int, expert: Expert, t: float) -> tuple[Tensor, Tensor]:
        """``([len(frame(t)), M], [len(frame(t)), 1])``: expert ``k``'s parameters of ``frame(t)``."""
        mix, time = self.mix[k], self.time[k]
        if mix.shape[0] != expert.num_gaussians:
            raise ValueError(
                f"routing weights of expert {k} ({expert.name}) have {mix.shape[0]} rows, the expert has "
                f"{expert.num_gaussians} Gaussians; were they pruned separately?"
            )
        index = expert.frame_rows(t)
        return (mix, time) if index is None else (mix[index], time[index])

    def keep(self, k: int, keep: Tensor) -> None:
        """Drop the rows of expert ``k`` where ``keep`` is False (gate-aware pruning)."""
        self.mix[k] = nn.Parameter(self.mix[k].detach()[keep].clone())
        self.time[k] = nn.Parameter(self.time[k].detach()[keep].clone())

    def param_groups(self) -> dict[str, list[Tensor]]:
        return {"w": list(self.mix), "w_time": list(self.time)}


def _phi(
    in_channels: int, hidden: Sequence[int], out_channels: int, kernel: int, bias: bool, device: torch.device
) -> nn.Sequential:
    """Conv MLP: ``in -> hidden... -> out`` with ReLU between, ``kernel`` x ``kernel``, same padding. Built on
    the CPU (its initialisation draws from the CPU generator, the same numbers on every machine), then moved
    to ``device``."""
    sizes = [in_channels, *hidden, out_channels]
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Conv2d(a, b, kernel, padding=kernel // 2, bias=bias, device="cpu"))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers).to(device)


def _softmax_gates(logits: Tensor, temperature: float) -> Tensor:
    return torch.softmax(logits / temperature, dim=0)


class VolumeAwarePixelRouter(nn.Module):
    """The paper's router. Parameters: ``weights`` (per Gaussian ``[w, w_dir, w_time]``), ``phi``
    (shared across experts: 8 -> 6 -> 3 -> 1 channels, ReLU, no bias, as the code's ``LiteSandwich``)."""

    def __init__(self, experts: Sequence[Expert], config: RouterConfig) -> None:
        super().__init__()
        self.config = config
        self.weights = GaussianWeights(experts, (config.init_w, config.init_w_dir), config.init_w_time)
        self.phi = _phi(2 + 6, (6, 3), 1, config.phi_kernel, bias=False, device=experts_device(experts))

    def param_groups(self) -> dict[str, list[Tensor]]:
        return {**self.weights.param_groups(), "phi": list(self.phi.parameters())}

    def features(self, k: int, expert: Expert, t: float) -> Tensor:
        """``[len(frame(t)), 3]``: ``[w, w_dir, t * w_time]`` of expert ``k``'s Gaussians at ``t``."""
        mix, time = self.weights.rows(k, expert, t)
        return torch.cat([mix, t * time], dim=1)

    def logits(self, maps: Tensor, alphas: Tensor, camera: Camera) -> Tensor:
        """``R' [K, H, W]`` from splatted ``maps [K, H, W, 3]`` and ``alphas [K, H, W]``."""
        maps = maps + (1.0 - alphas)[..., None] * self.config.weight_background
        w2d = maps[..., 0]
        aux = maps[..., 1:].permute(0, 3, 1, 2)  # [K, 2, H, W]: w2D_dir, w2D_time
        rays = ray_features(camera).to(aux.dtype).expand(aux.shape[0], -1, -1, -1)
        return w2d + self.phi(torch.cat([aux, rays], dim=1))[:, 0]

    def forward(
        self, experts, camera, background, *, single_pass=True, backend="auto", inputs=None
    ) -> MoERender:
        inputs = expert_inputs(experts, camera, background) if inputs is None else inputs
        extras = [self.features(k, e, camera.time) for k, e in enumerate(experts)]
        splat = splat_experts(inputs, camera, extras=extras, single_pass=single_pass, backend=backend)
        logits = self.logits(splat.extras, splat.alphas, camera)
        temperature = self.config.train_temperature if self.training else self.config.eval_temperature
        gates = _softmax_gates(logits, temperature)
        image = (gates[..., None] * splat.images).sum(0)
        return MoERender(image, gates, splat.images, logits, splat.passes)


class PixelRouter(nn.Module):
    """Image-space router (paper Fig. "Router_detail", top-left): a conv MLP on every expert's colour
    ``[3K]``, the ray ``r(u) [6]`` and the time ``[1]`` predicts ``K`` logits per pixel; no Gaussian
    information. The paper gives no architecture: two hidden layers of ``pixel_hidden`` with ReLU and the
    same kernel as Phi (our reading), the output layer starting at zero so that every expert starts with
    the same logit, as every router of the authors' code starts (equal ``w``, one Phi shared by the
    experts). A randomly initialised output layer gave each expert its own initial bias: divided by the
    code's training temperature (0.01) the softmax was one-hot from the first step, its gradients vanished,
    and the router stayed on whichever expert drew the largest bias (issue 66, item 10)."""

    def __init__(self, experts: Sequence[Expert], config: RouterConfig) -> None:
        super().__init__()
        self.config = config
        k, h = len(experts), config.pixel_hidden
        self.phi = _phi(3 * k + 7, (h, h), k, config.phi_kernel, bias=True, device=experts_device(experts))
        with torch.no_grad():
            self.phi[-1].weight.zero_()
            self.phi[-1].bias.zero_()

    def param_groups(self) -> dict[str, list[Tensor]]:
        return {"phi": list(self.phi.parameters())}

    def forward(
        self, experts, camera, background, *, single_pass=True, backend="auto", inputs=None
    ) -> MoERender:
        inputs = expert_inputs(experts, camera, background) if inputs is None else inputs
        with torch.no_grad():
            splat = splat_experts(inputs, camera, single_pass=single_pass, backend=backend)
        images = splat.images
        k, h, w, _ = images.shape
        rays = ray_features(camera).to(images.dtype)
        time = images.new_full((1, h, w), camera.time)
        x = torch.cat([images.permute(0, 3, 1, 2).reshape(3 * k, h, w), rays, time])
        logits = self.phi(x[None])[0]
        temperature = self.config.train_temperature if self.training else self.config.eval_temperature
        gates = _softmax_gates(logits, temperature)
        return MoERender((gates[..., None] * images).sum(0), gates, images, logits, splat.passes)


class VolumeRouter(nn.Module):
    """Gates before rasterization (paper's volume-router ablation; the code's ``get_opacity_with_weight``
    multiplies opacity by a sigmoid of ``_spacetime_mask``, no time term, initialised at 0.9, so at
    sigmoid(0.9) = 0.71; no script calls it). Per Gaussian ``[w, w_time]``; gate ``sigmoid(w + t * w_time)``,
    initialised at ``1/K`` so that K overlapping reconstructions start near one surface's opacity (the
    time term and the initial value are ours). All experts' Gaussians are rendered together in one
    image (antialiased when any expert is). Gates reported per pixel are each expert's share of the
    accumulated opacity."""

    def __init__(self, experts: Sequence[Expert], config: RouterConfig) -> None:
        super().__init__()
        self.config = config
        share = min(1.0 / len(experts), 1.0 - 1e-6)
        self.weights = GaussianWeights(experts, (math.log(share / (1.0 - share)),), 0.0)

    def param_groups(self) -> dict[str, list[Tensor]]:
        return self.weights.param_groups()

    def gated(self, k: int, expert: Expert, t: float) -> Tensor:
        mix, time = self.weights.rows(k, expert, t)
        return torch.sigmoid(mix[:, 0] + t * time[:, 0])

    def forward(
        self, experts, camera, background, *, single_pass=True, backend="auto", inputs=None
    ) -> MoERender:
        inputs = expert_inputs(experts, camera, background) if inputs is None else inputs
        if any(inp.decode is not None for inp in inputs):
            raise ValueError(
                "the volume router renders all experts' Gaussians in one image, so every expert must splat "
                "RGB; an expert with a feature decoder (STG color='full') cannot take part"
            )
        t, k_all = camera.time, len(experts)
        frames = []
        for k, (expert, inp) in enumerate(zip(experts, inputs, strict=True)):
            rgb = frame_colors(inp.frame, camera)
            index = torch.full((len(inp.frame),), k, device=rgb.device)
            one_hot = torch.nn.functional.one_hot(index, k_all).to(rgb)
            frame = depth_culled(inp.frame, camera, inp.near, inp.far).with_colors(
                torch.cat([rgb, one_hot], dim=1)
            )
            frames.append(replace(frame, opacities=frame.opacities * self.gated(k, expert, t)))
        joint, _ = cat(frames)
        bg = inputs[0].background
        out = rasterize(
            joint,
            camera,
            background=None if bg is None else torch.cat([bg, bg.new_zeros(k_all)]),
            antialiased=any(inp.antialiased for inp in inputs),
            return_depth=False,
            backend=backend,
        )
        share = out.image[..., 3:].permute(2, 0, 1)  # [K, H, W], sums to alpha
        covered = out.alpha > 0
        gates = torch.where(covered, share / out.alpha.clamp_min(1e-12), 1.0 / k_all)
        with torch.no_grad():
            images = splat_experts(inputs, camera, single_pass=single_pass, backend=backend).images
        return MoERender(out.image[..., :3], gates, images, None, 1)


ROUTER_CLASSES = {"vapr": VolumeAwarePixelRouter, "pixel": PixelRouter, "volume": VolumeRouter}


def build_router(experts: Sequence[Expert], config: RouterConfig) -> nn.Module:
    """The router of ``config.variant`` for ``experts``, on their device (``experts_device``)."""
    return ROUTER_CLASSES[config.variant](experts, config)
