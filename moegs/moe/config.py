"""``RouterConfig``: stage-2 (router) training of MoE-GS, with the paper's and the authors' conventions.

Where the paper and the authors' code disagree (``../shared/specs/official_moegs.md`` section 1), the
dataclass defaults follow the paper's wording and the code's value is one field away. The paper's numbers
were produced by the code, so the tables are reproduced with the code's conventions: presets ``code``
(paper scale) and ``quick`` (its CPU reduction); ``paper`` and ``quick-paper`` are the wording variants
(:func:`router_preset` picks one):

=====================  ==========================================  ==================================
field                  paper (default)                             authors' code
=====================  ==========================================  ==================================
``phi_kernel``         3: our reading of "convolutional MLP ...     1: every Conv2d of ``LiteSandwich``
                       local pixel context" (no size given)         is 1x1
``init_w_dir``         0.0: "neutral near-zero constants"           0.9 (= ``init_mixprob``, like w)
``train_temperature``  1.0: the paper has no temperature            0.01 (logits / 0.01 in training)
``eval_temperature``   1.0                                          1.0 (plain softmax at evaluation)
=====================  ==========================================  ==================================

Both conventions feed r(u) as the code builds it, camera origin and unit direction (6 channels, so Phi
takes 8); the paper calls r(u) the "pixel viewing direction". The learning rates are the paper's on N3V,
the code's per dataset elsewhere (``CODE_LEARNING_RATES``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from moegs.io.config import Presets
from moegs.recipes import override_key

ROUTERS = ("vapr", "pixel", "volume")
"""Router variants: volume-aware pixel router (the paper's), pixel router, volume router (ablation)."""
QUICK_ROUTER_ITERATIONS = 300
PAPER_ROUTER_ITERATIONS = 5000
CODE_PRUNE_EVERY = 500
"""``prune_weight_interval`` and ``prune_from_iter`` (MoE-GS-studio ``arguments/__init__.py``)."""


@dataclass
class RouterConfig(Presets):
    """Settings of one router and its training (experts frozen, router parameters only)."""

    variant: str = "vapr"
    """``"vapr"`` (volume-aware pixel router), ``"pixel"`` (image-space MLP, no Gaussian information) or
    ``"volume"`` (per-Gaussian gates on opacity before rasterization, one joint render)."""
    iterations: int = PAPER_ROUTER_ITERATIONS
    """Training iterations, one view per iteration (code: 5000 on N3V and Technicolor,
    ``scripts_MoE-GS/train_E4.sh``, ``train_E3_tech.sh``; the paper gives no count)."""
    seed: int = 0
    """Seeds the view order."""
    lambda_dssim: float = 0.2
    """Loss = (1 - lambda) L1 + lambda (1 - SSIM) (code ``lambda_dssim`` 0.2; paper: "L1 and SSIM")."""

    # -- volume-aware pixel router --------------------------------------------------------------------
    init_w: float = 0.9
    """Initial base weight w_i of every Gaussian of every expert (code ``init_mixprob``; the paper gives
    none). Equal for all experts, so the initial blend is neutral."""
    init_w_dir: float = 0.0
    """Initial view-dependent weight w_i^dir: paper "near-zero" (default); code 0.9."""
    init_w_time: float = 0.0
    """Initial time-dependent weight w_i^time (paper and code: 0)."""
    weight_background: float = 1.0
    """Value of the splatted weight maps where no Gaussian covers the pixel (code ``bg=[1,1,1]``: equal
    logits there, so a uniform blend)."""
    phi_kernel: int = 3
    """Kernel size of the router network Phi (8 -> 6 -> 3 -> 1 channels, ReLU, no bias): 3 (paper's
    "convolutional MLP") or 1 (code)."""
    train_temperature: float = 1.0
    """Softmax temperature while training: paper none (1.0); code 0.01."""
    eval_temperature: float = 1.0
    """Softmax temperature at evaluation (paper and code: 1.0)."""

    # -- pixel router ---------------------------------------------------------------------------------
    pixel_hidden: int = 32
    """Width of the pixel router's two hidden layers (our choice; the paper gives no architecture and
    the authors' code has no pixel router)."""

    # -- optimisation (code: RAdam; paper: 0.5 for w, w_dir and 0.05 for Phi, w_time; the code's rates
    # -- differ on Technicolor, see CODE_LEARNING_RATES) ------------------------------------------------
    optimizer: str = "radam"
    """``"radam"`` (code) or ``"adam"``."""
    lr_w: float = 0.5
    """Rate of w and w_dir (and of the volume router's gate logits), decayed exponentially."""
    lr_w_final_ratio: float = 0.01
    """w / w_dir rate decays to ``lr_w * lr_w_final_ratio`` over ``lr_w_decay_steps`` (code)."""
    lr_w_decay_steps: int | None = None
    """Decay length; None = 2 x iterations (code: 10000 steps for 5000 iterations)."""
    lr_time: float = 0.05
    """Rate of w_time, constant."""
    lr_phi: float = 0.05
    """Rate of Phi (and of the pixel router's MLP), constant."""

    # -- progressive gate-aware pruning (paper: "progressively pruned"; the code's unused schedule) ------
    prune_every: int = 0
    """Prune while training every this many iterations (code ``prune_weight_interval`` 500,
    ``arguments/__init__.py``); 0: none (``moegs.moe.prune.prune`` prunes a trained model once)."""
    prune_from: int = 500
    """First pruning iteration (code ``prune_from_iter``)."""
    prune_threshold: float = 1e-5
    """Remove Gaussians whose loss-gradient score is below this (code ``configs/N3V/*.json``
    ``prune_weight_threshold``; ``moegs.moe.prune.WeightGradients``)."""

    # -- run ------------------------------------------------------------------------------------------
    single_pass: bool = True
    """Render the experts and their weight maps in one pass (``rasterize_multi``) while training."""
    checkpoint_every: int = 0
    """Write a resumable checkpoint every this many iterations (0: only at the end)."""
    max_eval_views: int | None = None
    """Evaluate on at most this many test views, evenly spaced (None: all)."""
    metric_profile: str = "moegs"
    backend: str = "auto"

    def __post_init__(self) -> None:
        if self.variant not in ROUTERS:
            raise ValueError(f"RouterConfig.variant must be one of {ROUTERS}, got {self.variant!r}")
        if self.iterations < 1:
            raise ValueError(f"RouterConfig.iterations must be >= 1, got {self.iterations}")
        if self.phi_kernel not in (1, 3):
            raise ValueError(f"RouterConfig.phi_kernel must be 1 or 3, got {self.phi_kernel}")
        for name in ("train_temperature", "eval_temperature"):
            if getattr(self, name) <= 0:
                raise ValueError(f"RouterConfig.{name} must be positive, got {getattr(self, name)}")
        if self.prune_every < 0 or self.prune_from < 1:
            raise ValueError(
                f"RouterConfig.prune_every must be >= 0 and prune_from >= 1, got {self.prune_every}, "
                f"{self.prune_from}"
            )

    def with_progressive_pruning(self) -> RouterConfig:
        """This config pruning on the code's schedule (every 500 of 5000 iterations from 500) moved to
        the same fractions of its own run."""
        every = max(round(CODE_PRUNE_EVERY * self.iterations / PAPER_ROUTER_ITERATIONS), 1)
        return replace(self, prune_every=every, prune_from=every)

    @property
    def decay_steps(self) -> int:
        return self.lr_w_decay_steps if self.lr_w_decay_steps is not None else 2 * self.iterations

    @classmethod
    def presets(cls) -> dict[str, Callable[[], RouterConfig]]:
        """``code`` (5000 iterations, the authors' code conventions: 1x1 Phi, w_dir = 0.9, training
        temperature 0.01), ``paper`` (5000 iterations, the paper's wording), and their CPU reductions
        ``quick`` / ``quick-paper`` (300 iterations with Adam, 8 evaluation views)."""

        def code() -> RouterConfig:
            return cls(phi_kernel=1, init_w_dir=0.9, train_temperature=0.01)

        def quick(base: RouterConfig) -> RouterConfig:
            # quick: RAdam -> Adam (RAdam's variance warm-up keeps its step at ~20 % of Adam's for the first
            # few hundred steps; over 300 steps the router would barely move)
            return replace(base, iterations=QUICK_ROUTER_ITERATIONS, max_eval_views=8, optimizer="adam")

        return {
            "code": code,
            "paper": cls,
            "quick": lambda: quick(code()),
            "quick-paper": lambda: quick(cls()),
        }


CODE_LEARNING_RATES: dict[str, dict[str, float]] = {
    "technicolor": {"lr_w": 0.1, "lr_time": 0.01, "lr_phi": 0.01},
    "technicolor:fabien": {"lr_w": 0.05, "lr_time": 0.005, "lr_phi": 0.005},
}
"""The authors' router rates (``featuret_lr``, ``feature_lr``, ``rgb_lr``) where they depart from N3V's
0.5 / 0.05 / 0.05, the paper's (``configs/techni/*.json``; ``specs/official_moegs.md`` section 1), by
``<dataset>`` or ``<dataset>:<scene>``; the ``code`` convention applies them (:func:`router_config_for`)."""

CONVENTIONS = ("code", "paper")
"""``code``: the authors' code (what produced the paper's numbers); ``paper``: the paper's wording."""


def router_preset(scale: str, convention: str = "code") -> str:
    """The ``RouterConfig`` preset of a run scale (``quick`` or ``paper``) and a convention."""
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown router convention {convention!r}; valid: {', '.join(CONVENTIONS)}")
    if scale == "quick":
        return "quick" if convention == "code" else "quick-paper"
    if scale == "paper":
        return convention
    raise ValueError(f"unknown router scale {scale!r}; valid: quick, paper")


def router_config_for(
    scale: str, convention: str = "code", *, scene: str, dataset: str | None = None
) -> RouterConfig:
    """The ``RouterConfig`` of a run scale and convention on ``scene`` (``<dataset>:<scene>``, e.g.
    ``"technicolor:fabien"``): :func:`router_preset`, then, under the ``code`` convention, the authors'
    per-dataset and per-scene rates (``CODE_LEARNING_RATES``). ``dataset`` defaults to the scene's, as
    for the experts (``moegs.recipes.override_key``); a stand-in may name the dataset it stands for."""
    config = RouterConfig.from_preset(router_preset(scale, convention))
    if convention != "code":
        return config
    dataset, key = override_key(scene, dataset)
    return replace(config, **CODE_LEARNING_RATES.get(key, CODE_LEARNING_RATES.get(dataset, {})))
