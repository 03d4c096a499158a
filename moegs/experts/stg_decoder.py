"""STG's feature-splatting colour decoder (``helper_model.py`` ``Sandwich`` / ``Sandwichnoact``).

The full STG model splats 9 channels per pixel: albedo ``A`` (3), specular feature ``S`` (3) and time
feature ``T`` (3, already multiplied by ``Δt``). A bias-free 1x1-convolution MLP turns them into RGB
with the pixel's ray::

    rgb = act(A + W2 ReLU(W1 [S, T, r_o, r_d]))      W1: 12 -> 6, W2: 6 -> 3, no biases

where ``r_o`` is the camera centre and ``r_d`` the unit world direction of the pixel, and ``act`` is a
sigmoid (N3V, ``sandwich``) or a clamp to [0, 1] (Technicolor, ``sandwichnoact``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from moegs.camera import Camera

FEATURE_CHANNELS = 9
ACTIVATIONS = ("sigmoid", "clamp")
_BACKGROUND_LOGIT_CLAMP = 1e-3  # keeps logit(background) finite for pure black / white


class FeatureDecoder(nn.Module):
    """``[H, W, 9]`` splatted features + camera rays -> ``[H, W, 3]`` RGB (PyTorch default init, as the
    original ``Conv2d`` layers)."""

    def __init__(self, activation: str = "sigmoid") -> None:
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"FeatureDecoder activation must be one of {ACTIVATIONS}, got {activation!r}")
        self.activation = activation
        self.mlp1 = nn.Linear(12, 6, bias=False)
        self.mlp2 = nn.Linear(6, 3, bias=False)

    def forward(self, features: Tensor, camera: Camera) -> Tensor:
        if features.ndim != 3 or features.shape[-1] != FEATURE_CHANNELS:
            raise ValueError(
                f"FeatureDecoder expects [H, W, {FEATURE_CHANNELS}] features, got {list(features.shape)}"
            )
        if features.shape[:2] != (camera.height, camera.width):
            raise ValueError(
                f"features are {features.shape[1]}x{features.shape[0]} but the camera is "
                f"{camera.width}x{camera.height}"
            )
        origins, dirs = camera.rays()  # [H, W, 3] each
        albedo, rest = features[..., :3], features[..., 3:]
        h = torch.relu(
            self.mlp1(torch.cat([rest, origins.to(features.dtype), dirs.to(features.dtype)], dim=-1))
        )
        rgb = albedo + self.mlp2(h)
        return torch.sigmoid(rgb) if self.activation == "sigmoid" else rgb.clamp(0.0, 1.0)

    def background(self, rgb: Tensor) -> Tensor:
        """Feature background ``[9]`` for an RGB background ``[3]``: albedo = the pre-activation of the
        colour (``logit`` for the sigmoid decoder), zero features. STG itself splats on zeros and only
        uses black-background data; this keeps empty pixels at the dataset's background colour."""
        albedo = (
            torch.logit(rgb.clamp(_BACKGROUND_LOGIT_CLAMP, 1 - _BACKGROUND_LOGIT_CLAMP))
            if self.activation == "sigmoid"
            else rgb
        )
        return torch.cat([albedo, rgb.new_zeros(FEATURE_CHANNELS - 3)])
