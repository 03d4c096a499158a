"""``--set FIELD=VALUE`` checked before any work: each value is parsed by the type of the config field it
names, and a dedicated flag (``--seed``, ``--iterations``, ``--resolution-scale``, ``--checkpoint-every``)
and a ``--set`` of the same field must agree.

    --set train.batch_size=true   ->  --set train.batch_size=true: train.batch_size expects an int, got true
    --seed 1 --set train.seed=5   ->  --seed 1 and --set train.seed=5 disagree; give one of them

Types come from the config dataclasses' annotations (``int``, ``float``, ``bool``, ``str``, ``X | None``,
``tuple[...]``); ranges from ``RANGES`` below and from the config's own checks (``__post_init__``), whose
message is prefixed with the ``--set`` item that failed them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any

from moegs.io.config import tuples_for_lists

FLAG_FIELDS = {
    "--seed": "train.seed",
    "--iterations": "train.iterations",
    "--resolution-scale": "train.resolution_scale",
    "--checkpoint-every": "train.checkpoint_every",
}
"""Dedicated flags of ``moegs train`` and the config field each one sets."""

COUNTS = ("iterations", "batch_size")
"""Counts that must be at least 1 (as must every ``max_*``)."""
OFF_AT_ZERO = ("eval_every", "checkpoint_every", "adjust_every")
"""``*_every`` fields whose 0 means "never" (every other ``*_every`` divides the step: at least 1)."""


def _positive(v: float) -> bool:
    return v >= 1


RANGES: tuple[tuple[Callable[[str], bool], Callable[[Any], bool], str], ...] = (
    (lambda name: name in COUNTS or name.startswith("max_"), _positive, "a positive int"),
    (lambda name: name in OFF_AT_ZERO, lambda v: v >= 0, "an int >= 0 (0: never)"),
    (lambda name: name.endswith("_every"), _positive, "a positive int"),
    (lambda name: name == "seed", lambda v: 0 <= v < 2**63, "an int seed in [0, 2**63)"),
    (lambda name: name == "resolution_scale", lambda v: 0 < v <= 1, "a scale in (0, 1]"),
)
"""``(applies to the leaf name, holds for the value, what is expected)``: the first that applies is checked
(None always passes where the field allows it)."""


def split_items(items: list[str]) -> dict[str, str]:
    """``["train.iterations=100"]`` -> ``{"train.iterations": "100"}`` (the text after the first ``=``)."""
    out: dict[str, str] = {}
    for item in items:
        field, sep, text = item.partition("=")
        if not sep or not field:
            raise ValueError(f"--set expects FIELD=VALUE (e.g. train.iterations=100), got {item!r}")
        if field in out and out[field] != text:
            raise ValueError(f"--set {field} is given twice ({out[field]} and {text}); give it once")
        out[field] = text
    return out


def field_type(config: Any, dotted: str) -> Any:
    """The annotation of the dotted field of the dataclass ``config`` (``KeyError`` naming the valid fields;
    a group of fields such as ``train`` is refused, it has no value of its own)."""
    node = config
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        if not dataclasses.is_dataclass(node):
            raise KeyError(f"{'.'.join(parts[:i])} is not a group of fields; cannot set {dotted!r}")
        names = {f.name for f in dataclasses.fields(node)}
        if part not in names:
            raise KeyError(
                f"{type(node).__name__} has no field {part!r} (in {dotted!r}); fields: {sorted(names)}"
            )
        hint = typing.get_type_hints(type(node)).get(part, type(getattr(node, part)))
        node = getattr(node, part)
    if dataclasses.is_dataclass(node):
        example = dataclasses.fields(node)[0].name
        raise KeyError(f"{dotted!r} is a group of fields; set one of them, e.g. {dotted}.{example}=...")
    return hint


class _Refused(ValueError):
    """A text that is not a value of the type (the caller names the field)."""


def _describe(hint: Any) -> str:
    """``an int``, ``a number``, ``an int or null``, ``3 numbers``: what a type expects, in words."""
    args = typing.get_args(hint)
    if _is_union(hint):
        return " or ".join(_describe(a) for a in args if a is not type(None)) + " or null"
    if typing.get_origin(hint) is tuple:
        each = _describe(args[0]).removeprefix("an ").removeprefix("a ")
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {each}s (e.g. [1, 2] or 1,2)"
        return f"{len(args)} {each}s (e.g. [{', '.join(['1'] * len(args))}] or {','.join(['1'] * len(args))})"
    return {int: "an int", float: "a finite number", bool: "true or false", str: "a string"}.get(
        hint, f"a {getattr(hint, '__name__', hint)}"
    )


def _is_union(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def parse_value(text: str, hint: Any) -> Any:
    """``text`` as a value of the annotation ``hint``; ``_Refused`` when it is not one."""
    if _is_union(hint):
        if text.strip() in ("null", "None") and type(None) in typing.get_args(hint):
            return None
        for arg in (a for a in typing.get_args(hint) if a is not type(None)):
            try:
                return parse_value(text, arg)
            except _Refused:
                pass
        raise _Refused
    if typing.get_origin(hint) is tuple:
        value = _json(text)
        items = value if isinstance(value, list) else text.split(",")
        args = typing.get_args(hint)
        each = [args[0]] * len(items) if len(args) == 2 and args[1] is Ellipsis else list(args)
        if len(each) != len(items):
            raise _Refused
        texts = [v if isinstance(v, str) else json.dumps(v) for v in items]
        return tuple(parse_value(t, kind) for t, kind in zip(texts, each, strict=True))
    value = _json(text)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise _Refused
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        try:
            return int(text)  # 10_000
        except ValueError:
            raise _Refused from None
    if hint is float:
        if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            return float(value)
        raise _Refused
    if hint is str:
        return value if isinstance(value, str) else text.strip()
    if typing.get_origin(hint) is dict:
        return tuples_for_lists(value)  # a config's sequences are tuples, nested ones too
    return value  # another annotation: JSON, as before


def _range_error(leaf: str, value: Any) -> str | None:
    """What ``RANGES`` expects of ``leaf`` when ``value`` is outside it, else None."""
    if value is None or isinstance(value, bool) or not isinstance(value, int | float):
        return None
    for applies, holds, expected in RANGES:
        if applies(leaf):
            return None if holds(value) else expected
    return None


def typed_overrides(config: Any, texts: Mapping[str, str]) -> dict[str, Any]:
    """``--set`` texts (:func:`split_items`) parsed against the dataclass ``config``: dotted field -> value.

    Raises:
        KeyError: an unknown field (the message lists the valid ones).
        ValueError: ``--set F=T: F expects <type>, got T`` (or the range it expects).
    """
    out = {}
    for field, text in texts.items():
        hint = field_type(config, field)
        try:
            value = parse_value(text, hint)
        except _Refused:
            raise ValueError(f"--set {field}={text}: {field} expects {_describe(hint)}, got {text}") from None
        expected = _range_error(field.rsplit(".", 1)[-1], value)
        if expected:
            raise ValueError(f"--set {field}={text}: {field} expects {expected}, got {text}")
        out[field] = value
    return out


def with_flags(
    overrides: Mapping[str, Any], texts: Mapping[str, str], flags: Mapping[str, Any]
) -> dict[str, Any]:
    """``overrides`` with the dedicated flags given (``flags``: flag -> value, None when not given) set; a
    flag and a ``--set`` (``texts``) of one field that disagree raise ``ValueError`` naming both."""
    out = dict(overrides)
    for flag, value in flags.items():
        if value is None:
            continue
        field = FLAG_FIELDS[flag]
        if field in out and out[field] != value:
            raise ValueError(f"{flag} {value} and --set {field}={texts[field]} disagree; give one of them")
        out[field] = value
    return out


def checked_config(
    build: Callable[[Mapping[str, Any]], Any], overrides: Mapping[str, Any], texts: Mapping[str, str]
) -> Any:
    """``build(overrides)`` (e.g. ``config_for`` with them); a ``ValueError`` of the config's own checks
    names the overrides that fail them (each tried alone, else all of them) as given (``texts``)."""
    try:
        return build(overrides)
    except ValueError as err:
        if not overrides:
            raise
        culprits = [f for f, v in overrides.items() if not _builds(build, {f: v})]
        named = culprits or list(overrides)
        given = " ".join(f"{f}={texts.get(f, json.dumps(overrides[f]))}" for f in named)
        raise ValueError(f"--set {given}: {err}") from err


def _builds(build: Callable[[Mapping[str, Any]], Any], overrides: Mapping[str, Any]) -> bool:
    try:
        build(overrides)
    except ValueError:
        return False
    return True
