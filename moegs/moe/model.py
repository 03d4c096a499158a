"""``MoEGS``: frozen experts + one router, rendered as one model; its checkpoint.

model = MoEGS([ex4dgs, stg], RouterConfig.from_preset("quick"))
out = model.render(camera, scene.background)     # out.image [H, W, 3], out.gates [K, H, W]
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from moegs.camera import Camera
from moegs.data.scene import ImageCache, Scene
from moegs.experts.base import Expert, SplatInputs
from moegs.io import from_dict, load_checkpoint, to_dict
from moegs.moe.config import RouterConfig
from moegs.moe.routers import MoERender, build_router, experts_device

ROUTER_CHECKPOINT = "router.safetensors"
FORMAT = 1


class MoEGS(nn.Module):
    """Experts (frozen, always in eval mode) and the router that blends them, on the experts' device (move
    the experts with ``expert.to(device)`` before building it).

    Attributes:
        experts: ``K`` trained experts; no parameter of theirs requires grad.
        router: the router of ``config.variant`` (the only trainable part).
        config: the ``RouterConfig``.
        responsibilities: lifted gate responsibilities per expert ``[N_k]`` (``moegs.moe.lift``), or None.
        kept: after gate-aware pruning, which of each expert's trained Gaussians remain (bool, one
            ``[N_k trained]`` per expert), or None (``moegs.moe.prune``).
    """

    def __init__(self, experts: Sequence[Expert], config: RouterConfig) -> None:
        super().__init__()
        if not experts:
            raise ValueError("MoEGS needs at least one expert")
        self.config = config
        self.experts = nn.ModuleList(experts)
        self.experts.requires_grad_(False)
        self.router = build_router(experts, config)
        self.responsibilities: list[Tensor] | None = None
        self.kept: list[Tensor] | None = None
        self.train(False)

    def train(self, mode: bool = True) -> MoEGS:
        """Router in ``mode``; experts stay in eval mode (their test-time behaviour is what is blended)."""
        super().train(mode)
        self.experts.eval()
        return self

    @property
    def device(self) -> torch.device:
        """The experts' device, where the router and every tensor of a render live."""
        return experts_device(self.experts)

    @property
    def num_experts(self) -> int:
        return len(self.experts)

    @property
    def num_gaussians(self) -> int:
        return sum(e.num_gaussians for e in self.experts)

    def render(
        self,
        camera: Camera,
        background: Tensor | None,
        single_pass: bool | None = None,
        backend: str | None = None,
        inputs: Sequence[SplatInputs] | None = None,
    ) -> MoERender:
        """The routed view at ``camera.time`` (``single_pass``/``backend`` default to the config's;
        ``inputs``: the experts' ``splat_inputs`` for ``camera``, when the caller keeps them)."""
        return self.router(
            list(self.experts),
            camera,
            background,
            single_pass=self.config.single_pass if single_pass is None else single_pass,
            backend=backend or self.config.backend,
            inputs=inputs,
        )

    def expert_inputs(
        self, camera: Camera, background: Tensor | None, cache: ImageCache
    ) -> list[SplatInputs]:
        """Every frozen expert's ``splat_inputs`` for ``camera``, each computed once per its
        ``splat_inputs_key`` while ``cache`` holds it (the experts never change, so neither do they)."""
        with torch.no_grad():
            return [
                cache.get((k, e.splat_inputs_key(camera)), lambda e=e: e.splat_inputs(camera, background))
                for k, e in enumerate(self.experts)
            ]

    def checkpoint_state(self) -> dict[str, Any]:
        """What ``load_moe`` needs besides the experts."""
        return {
            "format": FORMAT,
            "config": to_dict(self.config),
            "experts": [e.name for e in self.experts],
            "num_gaussians": trained_counts(self),
            "router": dict(self.router.state_dict()),
            "responsibilities": self.responsibilities,
            "kept": self.kept,
        }


def trained_counts(model: MoEGS) -> list[int]:
    """Each expert's number of Gaussians as trained (before any gate-aware pruning)."""
    if model.kept is None:
        return [e.num_gaussians for e in model.experts]
    return [int(mask.numel()) for mask in model.kept]


def apply_kept(experts: Sequence[Expert], kept: Sequence[Tensor] | None) -> None:
    """Prune ``experts`` in place to a pruned router's ``kept`` rows (None: nothing); an expert already
    pruned to them (the objects the router trained over) stays as it is."""
    if kept is None:
        return
    for expert, mask in zip(experts, kept, strict=True):
        if expert.num_gaussians == mask.numel():
            expert.keep_gaussians(mask.to(device=experts_device(experts), dtype=torch.bool))


def _check_experts(state: dict, experts: Sequence[Expert], path: Path) -> None:
    names = [e.name for e in experts]
    if state["experts"] != names:
        raise ValueError(f"{path}: router was trained for experts {state['experts']}, got {names}")
    counts = [e.num_gaussians for e in experts]
    kept = state.get("kept")
    pruned = list(state["num_gaussians"]) if kept is None else [int(m.sum()) for m in kept]
    if any(
        n not in (trained, now)
        for n, trained, now in zip(counts, state["num_gaussians"], pruned, strict=True)
    ):
        raise ValueError(
            f"{path}: router was trained for experts with {state['num_gaussians']} Gaussians, got {counts}; "
            "load the same expert checkpoints the router was trained on"
        )


def read_router(path: str | Path) -> dict[str, Any]:
    """The router checkpoint at ``path`` (the file or its run folder), format checked."""
    path = Path(path)
    if path.is_dir():
        path = path / ROUTER_CHECKPOINT
    if not path.is_file():
        raise FileNotFoundError(f"no router checkpoint at {path} (written by moegs.moe.train_router)")
    state = load_checkpoint(path)
    if state.get("format") != FORMAT:
        raise ValueError(
            f"{path}: router checkpoint format {state.get('format')!r}, this moegs reads {FORMAT}"
        )
    return state


def load_moe(path: str | Path, experts: Sequence[Expert], scene: Scene | None = None) -> MoEGS:
    """The trained MoE-GS model of ``path`` (a ``train_router`` folder or its checkpoint) over ``experts``
    (the same trained experts, in the same order; a router pruned while training prunes them in place to
    its rows); with ``scene``, a router trained on another scene is refused. Returned in eval mode."""
    state = read_router(path)
    _check_experts(state, experts, Path(path))
    if scene is not None:
        scene.check_identity(state.get("scene"), path)
    apply_kept(experts, state.get("kept"))
    model = MoEGS(experts, from_dict(RouterConfig, state["config"]))
    model.kept = state.get("kept")
    model.router.load_state_dict(state["router"])
    resp = state.get("responsibilities")
    model.responsibilities = None if resp is None else [r.to(model.device) for r in resp]
    return model.eval()


@torch.no_grad()
def winner_coherence(gates: Tensor, window: int = 5) -> float:
    """Spatial coherence of the winner map of ``gates [K, H, W]``: the fraction of pixels whose winning
    expert is also the most frequent winner of their ``window x window`` neighbourhood (ties count as
    agreement; the neighbourhood is clipped at the image border). 1/K-ish for noise, near 1 for regions."""
    k = gates.shape[0]
    winner = gates.argmax(0)
    onehot = torch.nn.functional.one_hot(winner, k).permute(2, 0, 1).float()[None]  # [1, K, H, W]
    votes = torch.nn.functional.avg_pool2d(
        onehot, window, stride=1, padding=window // 2, count_include_pad=False
    )[0]  # [K, H, W]
    own = votes.gather(0, winner[None])[0]
    return float((own >= votes.max(0).values - 1e-6).float().mean())


@torch.no_grad()
def region_shares(gates: Tensor, mask: Tensor) -> dict[str, list[float]]:
    """Share of the dynamic (``mask > 0.5``) and of the static pixels won by each expert (argmax of
    ``gates [K, H, W]``): ``{"dynamic": [K], "static": [K]}``, each summing to 1 (empty region: zeros)."""
    k = gates.shape[0]
    winner = gates.argmax(0)
    out = {}
    for name, region in (("dynamic", mask > 0.5), ("static", mask <= 0.5)):
        counts = torch.bincount(winner[region].flatten(), minlength=k).float()
        out[name] = (counts / counts.sum().clamp_min(1)).tolist()
    return out


@torch.no_grad()
def winner_share(gates: Tensor, margin: float = 1e-3) -> Tensor:
    """Fraction of pixels where each expert's gate is the largest and above the uniform ``1/K`` by
    ``margin`` (pixels no expert covers get equal logits and count for nobody), ``[K]`` on the gates'
    device."""
    k = gates.shape[0]
    top, winner = gates.max(0)
    decided = top > 1.0 / k + margin
    counts = torch.bincount(winner[decided].flatten(), minlength=k)
    return counts.div(gates[0].numel())


def winner_shares(gates: Tensor, margin: float = 1e-3) -> list[float]:
    """:func:`winner_share` as ``K`` floats."""
    return winner_share(gates, margin).tolist()
