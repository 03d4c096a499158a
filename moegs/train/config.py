"""``TrainConfig``: the settings of the one training loop that every expert shares."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrainConfig:
    """How to train (the method-specific parts live in each expert's config)."""

    iterations: int = 30_000
    """Number of training iterations (3DGS default 30k)."""
    batch_size: int = 1
    """Views per step drawn from each view group (3DGS-lineage methods: one image per step)."""
    lambda_dssim: float = 0.2
    """Loss = (1 - lambda) L1 + lambda (1 - SSIM) (3DGS ``lambda_dssim``)."""
    resolution_scale: float | None = None
    """``resolution_scale`` passed to the scene loader for this run (None: the loader's default, which
    is the dataset's protocol)."""
    sh_degree_interval: int = 1000
    """One more spherical-harmonics band every this many iterations, up to the expert's ``sh_degree``
    (3DGS ``oneupSHdegree`` every 1000, ``train.py``; every expert here inherits it)."""
    seed: int = 0
    """Seeds the initialisation subsampling, view order and every random op of training."""
    eval_every: int = 0
    """Evaluate on the test views every this many iterations (0: only at the end)."""
    select_best_at: tuple[int, ...] = ()
    """Score the test views at these iterations and also report the best-scoring model (``best`` beside
    the last model's ``test``; Grid4D's ``iteration_best``, ``moegs.train.select``). Empty: none."""
    checkpoint_every: int = 0
    """Write a checkpoint every this many iterations (0: only at the end)."""
    log_every: int = 10
    """Refresh the progress bar's loss / #Gaussians every this many iterations."""
    metric_profile: str = "moegs"
    """``moegs.metrics`` profile used for evaluation ("moegs" = the paper's conventions)."""
    max_eval_views: int | None = None
    """Evaluate on at most this many test views, evenly spaced (None: all)."""
    backend: str = "auto"
    """Rasterizer backend (``moegs.render.BACKENDS``)."""

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ValueError(f"TrainConfig.iterations must be >= 1, got {self.iterations}")
        if self.sh_degree_interval < 1:
            raise ValueError(f"TrainConfig.sh_degree_interval must be >= 1, got {self.sh_degree_interval}")
        self.select_best_at = tuple(self.select_best_at)
        if any(step < 1 for step in self.select_best_at):
            raise ValueError(
                f"TrainConfig.select_best_at must hold iterations >= 1, got {self.select_best_at}"
            )
        if self.batch_size < 1:
            raise ValueError(f"TrainConfig.batch_size must be >= 1, got {self.batch_size}")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise ValueError(f"TrainConfig.lambda_dssim must be in [0, 1], got {self.lambda_dssim}")
