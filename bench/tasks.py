"""Tasks: the units of work, content-addressed.

A ``Task`` either *builds* an artefact (a trained expert, a trained router, a MoDE model, a distilled
expert; kept in the checkpoint store and shared by every table that needs it) or *evaluates* a cell
(one number set for one method on one scene, written as one result JSON). Its key hashes everything
that changes its output: action, kind, parameters, scene and loader arguments, bench preset (name
and full definition), seed, device kind (``cpu`` or ``cuda``: CPU and GPU numbers never share a key) and
the version of the library code it can run (``bench.codedeps``). Two tables asking for the same thing on
the same kind of device get the same key, so the work is done once.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from bench.codedeps import task_code_version
from bench.keys import digest
from bench.presets import get_preset

SCHEMA = 1
ACTIONS = ("build", "eval")
DEVICE_KINDS = ("cpu", "cuda")
"""What a task runs on (``moegs.device.device_kind``); two GPUs compute alike, so the key has no index."""


def _plain(obj: Any) -> Any:
    """Mappings/tuples -> dicts/lists, recursively (JSON-ready)."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    return obj


def _named_experts(params: Any) -> set[str]:
    """Registered expert names among the (nested) string values of ``params``."""
    from moegs.experts import list_experts

    registered = {spec.name for spec in list_experts()}
    if isinstance(params, Mapping):
        return set().union(*(_named_experts(v) for v in params.values()))
    if isinstance(params, list | tuple):
        return set().union(*(_named_experts(v) for v in params))
    return {params} & registered if isinstance(params, str) else set()


@dataclass(frozen=True, eq=False)
class Task:
    """One build or evaluation.

    Attributes:
        action: ``"build"`` (artefact in the store) or ``"eval"`` (a result JSON).
        kind: the ``bench.cells`` module doing it (``expert``, ``moe``, ``mode``, ``distill`` ...).
        params: kind parameters (expert names, router variant, budget ...).
        scene: ``moegs.data.load_scene`` name.
        scene_kwargs: loader keyword arguments (from the preset).
        preset: bench preset name.
        seed: training seed.
        device: ``"cpu"`` or ``"cuda"`` (the worker runs a ``cuda`` task on its first visible GPU).
    """

    action: str
    kind: str
    params: Mapping[str, Any]
    scene: str
    scene_kwargs: Mapping[str, Any] = field(default_factory=dict)
    preset: str = "quick"
    seed: int = 0
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"Task.action must be one of {ACTIONS}, got {self.action!r}")
        if self.device not in DEVICE_KINDS:
            raise ValueError(f"Task.device must be one of {DEVICE_KINDS}, got {self.device!r}")
        object.__setattr__(self, "params", MappingProxyType(_plain(self.params)))
        object.__setattr__(self, "scene_kwargs", MappingProxyType(_plain(self.scene_kwargs)))

    def identity(self) -> dict[str, Any]:
        """Everything the key hashes."""
        return {
            "schema": SCHEMA,
            "action": self.action,
            "kind": self.kind,
            "params": dict(self.params),
            "scene": self.scene,
            "scene_kwargs": dict(self.scene_kwargs),
            "preset": self.preset,
            "preset_definition": digest(get_preset(self.preset).to_dict()),
            "seed": self.seed,
            "device": self.device,
            "code_version": self.code_version,
        }

    def code_dependencies(self) -> tuple[str, frozenset[str], str]:
        """``(kind, expert names, dataset)``: what ``bench.codedeps`` needs to find this task's code."""
        from moegs.data import parse_scene_name

        return self.kind, frozenset(_named_experts(self.params)), parse_scene_name(self.scene)[0]

    @property
    def code_version(self) -> str:
        """Hash of the library source this task can run (``bench.codedeps``)."""
        return task_code_version(*self.code_dependencies())

    @property
    def key(self) -> str:
        return digest(self.identity())

    @property
    def slug(self) -> str:
        """Short human-readable name for logs: ``expert-grid4d@dnerf:mutant#s0``."""
        p = self.params
        what = p.get("expert") or p.get("student") or "+".join(p.get("experts", [])) or self.kind
        extra = "".join(f"-{k}{p[k]}" for k in ("router", "budget", "prune", "weighted") if k in p)
        return f"{self.kind}-{what}{extra}@{self.scene}#s{self.seed}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "action": self.action,
            "kind": self.kind,
            "params": _plain(self.params),
            "scene": self.scene,
            "scene_kwargs": _plain(self.scene_kwargs),
            "preset": self.preset,
            "seed": self.seed,
            "device": self.device,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Task:
        fields = ("action", "kind", "params", "scene", "scene_kwargs", "preset", "seed")
        return cls(**{k: data[k] for k in fields}, device=data.get("device", "cpu"))

    def derive(self, action: str, kind: str, params: Mapping[str, Any]) -> Task:
        """A task on the same scene, preset, seed and device."""
        return Task(action, kind, params, self.scene, self.scene_kwargs, self.preset, self.seed, self.device)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Task) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)

    def __repr__(self) -> str:
        return f"Task({self.action} {self.slug} key={self.key})"


def dumps(task: Task) -> str:
    return json.dumps(task.to_dict(), sort_keys=True)
