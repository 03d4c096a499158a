"""Config dataclasses <-> JSON-ready dicts (nested dataclasses included).

``to_dict`` records the class of every nested dataclass under ``"_type"`` so a field typed with a
base class (e.g. a ``Strategy``) comes back as the right subclass.
"""

from __future__ import annotations

import dataclasses
import importlib
import types
import typing
from collections.abc import Callable, Mapping
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


def _subclass_named(bases: tuple[type, ...], name: str) -> type | None:
    """The class called ``name`` among ``bases`` and their (loaded) subclasses."""
    seen, todo = set(), list(bases)
    while todo:
        cls = todo.pop()
        if cls in seen:
            continue
        seen.add(cls)
        if _qualname(cls) == name:
            return cls
        todo.extend(cls.__subclasses__())
    return None


def _resolve(name: Any, bases: tuple[type, ...]) -> type:
    """The config class recorded as ``name`` (``module:Qualname``): one of ``bases`` or a subclass of one.
    Only ``moegs`` modules are imported to find it, so a crafted file cannot make loading import
    anything else."""
    expected = " or ".join(b.__name__ for b in bases)
    if not isinstance(name, str):
        raise ValueError(f"config {_TYPE} must be a 'module:Class' string, got {name!r}")
    found = _subclass_named(bases, name)
    module = name.partition(":")[0]
    if found is None and (module == "moegs" or module.startswith("moegs.")):
        try:
            importlib.import_module(module)
        except ImportError:
            pass
        found = _subclass_named(bases, name)
    if found is None:
        raise ValueError(f"config {_TYPE} {name!r} is not {expected} or a moegs subclass of it")
    return found


def _config_bases(hint: Any) -> tuple[type, ...]:
    """The dataclasses a field annotated ``hint`` may hold (``A``, ``A | None`` ...)."""
    options = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    return tuple(o for o in options if isinstance(o, type) and dataclasses.is_dataclass(o))


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
    if not isinstance(data, dict):
        raise ValueError(f"{cls.__name__}: expected a config object, got {type(data).__name__}")
    if _TYPE in data:
        cls = _resolve(data[_TYPE], (cls,))
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
            kwargs[name] = from_dict(_resolve(value[_TYPE], _config_bases(hint)), value)
        elif isinstance(value, list) and typing.get_origin(hint) is tuple:
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)


def tuples_for_lists(value: Any) -> Any:
    """``value`` with every list, nested ones included, as a tuple: the form config fields hold the
    sequences JSON reads back as lists (e.g. inside a ``dict[str, Any]`` field, which ``from_dict`` takes
    as it is)."""
    if isinstance(value, list | tuple):
        return tuple(tuples_for_lists(v) for v in value)
    if isinstance(value, dict):
        return {k: tuples_for_lists(v) for k, v in value.items()}
    return value


def config_changes(saved: dict, current: dict, ignore: tuple[str, ...] = (), prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two :func:`to_dict` configs, ``ignore`` aside."""
    out = []
    for key in sorted(set(saved) | set(current)):
        name = f"{prefix}{key}"
        a, b = saved.get(key), current.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_changes(a, b, ignore, f"{name}.")
        elif a != b and name not in ignore:
            out.append(name)
    return out


# -- dotted field access (recipes) -------------------------------------------------------------------
def with_fields(config: Any, changes: Mapping[str, Any]) -> Any:
    """A copy of the dataclass ``config`` with dotted fields replaced (``"strategy.densify_every"``).

    Nested dataclasses are rebuilt bottom-up with ``dataclasses.replace``, so ``__post_init__`` checks
    see the final values of every level at once. A list given for a tuple field becomes a tuple (values
    read back from JSON). Unknown names raise ``KeyError`` naming the valid ones.
    """
    if not changes:
        return config
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    names = {f.name for f in dataclasses.fields(config)}
    for dotted, value in changes.items():
        head, _, rest = dotted.partition(".")
        if head not in names:
            raise KeyError(
                f"{type(config).__name__} has no field {head!r} (in {dotted!r}); fields: {sorted(names)}"
            )
        if rest:
            nested.setdefault(head, {})[rest] = value
        elif isinstance(value, list) and isinstance(getattr(config, head), tuple):
            top[head] = tuple(value)
        else:
            top[head] = value
    for head, sub in nested.items():
        inner = top.get(head, getattr(config, head))
        if not dataclasses.is_dataclass(inner):
            raise KeyError(f"{type(config).__name__}.{head} is not a dataclass; cannot set {list(sub)}")
        top[head] = with_fields(inner, sub)
    return dataclasses.replace(config, **top)


def get_field(config: Any, dotted: str) -> Any:
    """The value of a dotted field (``"train.iterations"``)."""
    value = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def changed_fields(a: Any, b: Any, prefix: str = "") -> list[str]:
    """Dotted names of the leaf fields whose values differ between two configs of one class."""
    out = []
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        name = prefix + f.name
        if dataclasses.is_dataclass(x) and type(x) is type(y):
            out += changed_fields(x, y, name + ".")
        elif x != y:
            out.append(name)
    return out
