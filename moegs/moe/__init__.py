"""MoE-GS: independently trained experts blended by a learned router (paper Sec. "Mixture of Experts for
Dynamic Gaussian Splatting").

    from moegs.moe import RouterConfig, train_router, load_moe
    result = train_router([expert_a, expert_b], scene, RouterConfig.from_preset("quick"), "runs/moe")
    model = load_moe("runs/moe", [expert_a, expert_b])
    out = model.render(camera, scene.background)   # image [H, W, 3], gates [K, H, W], expert_images

Modules: ``config`` (RouterConfig, presets, paper vs code conventions), ``splat`` (experts rendered in a
single pass with per-Gaussian channels), ``routers`` (volume-aware pixel, pixel, volume routers),
``model`` (MoEGS, checkpoint), ``train`` (stage-2 training and evaluation), ``prune`` (gate-aware
pruning), ``distill`` (MoE-GS into one expert), ``lift`` (gate responsibilities per Gaussian, post-hoc
fusion), ``visualize`` (gate maps).
"""

from moegs.moe.config import ROUTERS, RouterConfig, router_config_for, router_preset
from moegs.moe.distill import DistillConfig, distill
from moegs.moe.lift import compute_responsibilities, lift
from moegs.moe.model import MoEGS, load_moe, region_shares, winner_coherence
from moegs.moe.prune import gate_importance, prune
from moegs.moe.routers import MoERender, PixelRouter, VolumeAwarePixelRouter, VolumeRouter
from moegs.moe.train import evaluate_moe, train_router

__all__ = [
    "ROUTERS",
    "DistillConfig",
    "MoEGS",
    "MoERender",
    "PixelRouter",
    "RouterConfig",
    "router_config_for",
    "router_preset",
    "VolumeAwarePixelRouter",
    "VolumeRouter",
    "compute_responsibilities",
    "distill",
    "evaluate_moe",
    "gate_importance",
    "lift",
    "load_moe",
    "prune",
    "region_shares",
    "winner_coherence",
    "train_router",
]
