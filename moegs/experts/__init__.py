"""Registry of experts, importable without torch.

Each entry names the class as a ``"module:Class"`` string; the module is imported only by
:func:`get_expert_class`, so ``moegs list`` stays light. Built-in experts are listed in ``_BUILTIN``.
Other packages add experts without touching moegs through the entry-point group ``moegs.experts``
(``name = "pkg.module:ExpertClass"`` in their ``pyproject.toml``; README "Add your own expert"), or at
run time with :func:`register`.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from functools import cache

ENTRY_POINT_GROUP = "moegs.experts"
EXPERTS_ENV = "MOEGS_EXPERTS"
"""``name=package.module:Class[,name=...]``: experts registered for this process and its children (how
``bench.all --candidate package.module:Class`` hands an unpackaged expert to its workers)."""


@dataclass(frozen=True)
class ExpertSpec:
    name: str
    target: str
    """``"package.module:Class"`` of the ``Expert`` subclass."""
    description: str
    composite: bool = False
    """Built from other experts (MoDE): left out of "all experts" lists such as ``moegs compare``."""
    plugin: str | None = None
    """The distribution whose ``moegs.experts`` entry point registered it (None: built in)."""

    @property
    def origin(self) -> str:
        """Where the expert comes from, for messages: ``"entry point 'x = pkg:X' of dist"``."""
        if self.plugin is None:
            return f"built-in {self.target}"
        return f"entry point {self.name!r} = {self.target!r} of {self.plugin}"


_BUILTIN: dict[str, ExpertSpec] = {
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


_ADDED: dict[str, ExpertSpec] = {}


@cache
def _plugins() -> dict[str, ExpertSpec]:
    """Experts registered by installed packages under ``ENTRY_POINT_GROUP`` (read once, no import)."""
    from importlib.metadata import entry_points

    found: dict[str, ExpertSpec] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        dist = ep.dist.name if ep.dist is not None else "an unknown distribution"
        where = f"expert plugin entry point {ep.name!r} = {ep.value!r} of {dist}"
        if ":" not in ep.value or ep.value.startswith(":") or ep.value.endswith(":"):
            raise ValueError(f"{where}: expected 'package.module:ExpertClass'")
        if ep.name in _BUILTIN:
            raise ValueError(f"{where}: {ep.name!r} is the name of a built-in expert; choose another")
        if ep.name in found:
            raise ValueError(f"{where}: {ep.name!r} is also registered by {found[ep.name].origin}")
        found[ep.name] = ExpertSpec(ep.name, ep.value, f"plugin expert from {dist}", plugin=dist)
    for item in filter(None, (i.strip() for i in os.environ.get(EXPERTS_ENV, "").split(","))):
        name, _, target = item.partition("=")
        if not name or ":" not in target:
            raise ValueError(f"${EXPERTS_ENV}: expected name=package.module:Class entries, got {item!r}")
        if name in _BUILTIN or name in found:
            raise ValueError(f"${EXPERTS_ENV}: {name!r} is already registered")
        found[name] = ExpertSpec(name, target, f"expert from ${EXPERTS_ENV}", plugin=f"${EXPERTS_ENV}")
    return found


def reload_plugins() -> None:
    """Read the installed entry points again (after installing a plugin in a running process)."""
    _plugins.cache_clear()


def _registry() -> dict[str, ExpertSpec]:
    return {**_BUILTIN, **_plugins(), **_ADDED}


def register(name: str, target: str, description: str) -> None:
    """Add an expert; ``target`` is ``"module:Class"``."""
    if ":" not in target:
        raise ValueError(f"expert target must look like 'package.module:Class', got {target!r}")
    if name in _registry():
        raise ValueError(f"expert {name!r} is already registered ({_registry()[name].target})")
    _ADDED[name] = ExpertSpec(name, target, description)


def list_experts() -> list[ExpertSpec]:
    """Registered experts (built-in, plugins, run-time additions), sorted by name (imports nothing)."""
    registry = _registry()
    return [registry[k] for k in sorted(registry)]


def get_spec(name: str) -> ExpertSpec:
    registry = _registry()
    if name not in registry:
        raise ValueError(f"unknown expert {name!r}; registered experts: {', '.join(sorted(registry))}")
    return registry[name]


def get_expert_class(name: str) -> type:
    """Import and return the ``Expert`` subclass registered as ``name``; a plugin that cannot be imported
    or does not follow the protocol fails with a message naming its entry point and what is missing."""
    spec = get_spec(name)
    module_name, _, attr = spec.target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ImportError(f"expert {name!r} ({spec.origin}): cannot import {module_name}: {err}") from err
    cls = getattr(module, attr, None)
    if cls is None:
        raise ValueError(f"expert {name!r} ({spec.origin}): module {module_name} has no {attr!r}")
    check_protocol(cls, name, spec.origin)
    return cls


def check_protocol(cls: object, name: str, origin: str) -> None:
    """``ValueError`` naming what an expert class lacks: an ``Expert`` subclass named ``name`` whose
    ``config_class`` is an ``ExpertConfig`` with ``quick`` and ``paper`` presets."""
    from moegs.experts.base import Expert, ExpertConfig

    where = f"expert {name!r} ({origin})"
    if not (isinstance(cls, type) and issubclass(cls, Expert)):
        raise ValueError(f"{where}: {cls!r} is not a subclass of moegs.experts.base.Expert")
    if cls.name != name:
        raise ValueError(f"{where}: the class sets name = {cls.name!r}; it must be {name!r}")
    config = getattr(cls, "config_class", None)
    if not (isinstance(config, type) and issubclass(config, ExpertConfig)):
        raise ValueError(f"{where}: config_class must be a moegs.experts.base.ExpertConfig subclass")
    try:
        presets = set(config.presets())
    except NotImplementedError:
        presets = set()
    missing = {"quick", "paper"} - presets
    if missing:
        raise ValueError(f"{where}: {config.__name__}.presets() lacks {sorted(missing)}")
