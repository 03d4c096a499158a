"""Config dataclasses <-> JSON-ready dicts (nested dataclasses included).

``to_dict`` records the class of every nested dataclass under ``"_type"`` so a field typed with a
base class (e.g. a ``Strategy``) comes back as the right subclass.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from collections.abc import Callable
from typing import Any, Self

_TYPE = "_type"


class Presets:
    """Mixin of config dataclasses with named presets: implement ``presets()``, get ``from_preset``."""

    @classmethod
    def presets(cls) -> dict[str, Callable[[], Self]]:
        """Named presets, e.g. ``"quick"`` (CPU minutes) and ``"paper"`` (the original protocol)."""
        raise NotImplementedError(f"{cls.__name__} defines no presets")

    @classmethod
    def from_preset(cls, name: str) -> Self:
        presets = cls.presets()
        if name not in presets:
            raise ValueError(
                f"unknown preset {name!r} for {cls.__name__}; valid presets: {', '.join(presets)}"
            )
        return presets[name]()


def _qualname(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _resolve(name: str) -> type:
    module, _, qual = name.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def to_dict(config: Any) -> dict:
    """A JSON-ready dict of a dataclass instance (tuples become lists)."""
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        raise TypeError(f"to_dict expects a dataclass instance, got {type(config).__name__}")

    def convert(value: Any) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return to_dict(value)
        if isinstance(value, list | tuple):
            return [convert(v) for v in value]
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        return value

    out = {f.name: convert(getattr(config, f.name)) for f in dataclasses.fields(config)}
    out[_TYPE] = _qualname(type(config))
    return out


def from_dict(cls: type, data: dict) -> Any:
    """Rebuild ``cls`` (or the subclass recorded in ``data``) from :func:`to_dict` output.

    Unknown keys raise ``ValueError`` naming them; missing keys keep their defaults.
    """
    if _TYPE in data:
        cls = _resolve(data[_TYPE])
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = set(data) - names - {_TYPE}
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown config keys {sorted(unknown)}; valid: {sorted(names)}")
    kwargs = {}
    for name, value in data.items():
        if name == _TYPE:
            continue
        hint = hints[name]
        if isinstance(value, dict) and _TYPE in value:
            kwargs[name] = from_dict(_resolve(value[_TYPE]), value)
        elif isinstance(value, list) and typing.get_origin(hint) is tuple:
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)
