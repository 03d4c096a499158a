"""MoDE: a Mixture of Deformation Experts on one shared canonical Gaussian set (paper Sec. "Mixture of
Deformation Experts (MoDE)"). ``MoDEExpert`` is an ``Expert`` (registry name ``"mode"``), trained by the
one training loop like any other.

    from moegs.mode import MoDEConfig, MoDEExpert
    mode = MoDEExpert.from_scene(scene, MoDEConfig.from_preset("quick"))   # fourdgs + ed3dgs
"""

from moegs.mode.expert import CANONICAL_EXPERTS, MoDEConfig, MoDEExpert
from moegs.mode.gating import top_k_gates, warmup_scores, weight_spline

__all__ = ["CANONICAL_EXPERTS", "MoDEConfig", "MoDEExpert", "top_k_gates", "warmup_scores", "weight_spline"]
