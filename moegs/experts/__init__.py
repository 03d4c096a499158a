"""Registry of experts, importable without torch.

Each entry names the class as a ``"module:Class"`` string; the module is imported only by
:func:`get_expert_class`, so ``moegs list`` stays light. Add an expert with one line in ``_REGISTRY``
(or :func:`register` at run time).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class ExpertSpec:
    name: str
    target: str
    """``"package.module:Class"`` of the ``Expert`` subclass."""
    description: str
    composite: bool = False
    """Built from other experts (MoDE): left out of "all experts" lists such as ``moegs compare``."""


_REGISTRY: dict[str, ExpertSpec] = {
    spec.name: spec
    for spec in (
        ExpertSpec(
            "static",
            "moegs.experts.static:StaticExpert",
            "3DGS without deformation, trained on all frames (baseline)",
        ),
        ExpertSpec(
            "mcmc",
            "moegs.experts.mcmc:MCMCExpert",
            "3DGS-MCMC trained per frame: one static model per time step",
        ),
        ExpertSpec(
            "deformable",
            "moegs.experts.deformable:DeformableExpert",
            "Deformable 3D Gaussians (Yang et al. 2024): MLP on PE(x), PE(t) deforms canonical 3DGS",
        ),
        ExpertSpec(
            "grid4d",
            "moegs.experts.grid4d:Grid4DExpert",
            "Grid4D (Xu et al. 2024): 4D decomposed hash grids + directional attention MLP",
        ),
        ExpertSpec(
            "fourdgs",
            "moegs.experts.fourdgs:FourDGSExpert",
            "4D Gaussian Splatting (Wu et al. 2024): HexPlane + small MLP, coarse static stage",
        ),
        ExpertSpec(
            "ed3dgs",
            "moegs.experts.ed3dgs:ED3DGSExpert",
            "E-D3DGS: per-Gaussian + temporal embeddings, coarse and fine MLP branches",
        ),
        ExpertSpec(
            "stg",
            "moegs.experts.stg:STGExpert",
            "Spacetime Gaussians: polynomial motion, temporal RBF opacity, feature splatting",
        ),
        ExpertSpec(
            "mode",
            "moegs.mode:MoDEExpert",
            "MoDE: canonical deformation experts on shared Gaussians, weight-spline top-k gating",
            composite=True,
        ),
        ExpertSpec(
            "ex4dgs",
            "moegs.experts.ex4dgs:Ex4DGSExpert",
            "Ex4DGS: static drift + keyframed dynamic Gaussians, progressive training",
        ),
    )
}


def register(name: str, target: str, description: str) -> None:
    """Add an expert; ``target`` is ``"module:Class"``."""
    if ":" not in target:
        raise ValueError(f"expert target must look like 'package.module:Class', got {target!r}")
    if name in _REGISTRY:
        raise ValueError(f"expert {name!r} is already registered ({_REGISTRY[name].target})")
    _REGISTRY[name] = ExpertSpec(name, target, description)


def list_experts() -> list[ExpertSpec]:
    """Registered experts, sorted by name (imports nothing)."""
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def get_spec(name: str) -> ExpertSpec:
    if name not in _REGISTRY:
        raise ValueError(f"unknown expert {name!r}; registered experts: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def get_expert_class(name: str) -> type:
    """Import and return the ``Expert`` subclass registered as ``name``."""
    module, _, cls = get_spec(name).target.partition(":")
    return getattr(importlib.import_module(module), cls)
