"""argparse types of the command line: values are checked before any work starts."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def _checked(parse: Callable[[str], T], ok: Callable[[T], bool], expected: str) -> Callable[[str], T]:
    """An argparse type: ``parse(text)``, rejected with ``expected ..., got '<text>'`` when it fails to
    parse or ``ok`` is false (a NaN fails every range test)."""

    def check(text: str) -> T:
        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return check


positive_int = _checked(int, lambda v: v >= 1, "a positive integer")
non_negative_int = _checked(int, lambda v: v >= 0, "an integer >= 0")
positive_float = _checked(float, lambda v: 0 < v < math.inf, "a positive number")
non_negative_float = _checked(float, lambda v: 0 <= v < math.inf, "a number >= 0")
seed = _checked(int, lambda v: 0 <= v < 2**63, "an integer seed in [0, 2**63)")
unit_time = _checked(float, lambda v: 0.0 <= v <= 1.0, "a time in [0, 1]")
unit_scale = _checked(float, lambda v: 0.0 < v <= 1.0, "a scale in (0, 1]")


def add_resume_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--checkpoint-every`` and ``--force`` of a command that trains ``what`` (train, route)."""
    parser.add_argument(
        "--checkpoint-every",
        type=positive_int,
        help=f"write a resumable {what} checkpoint every N iterations (default: a tenth of the run)",
    )
    parser.add_argument(
        "--force", action="store_true", help=f"train the {what} again even if its folder holds a finished run"
    )


def device(text: str):
    """argparse type: ``auto|cpu|cuda[:i]`` resolved to a ``torch.device`` (``moegs.device``): a device
    this machine lacks is refused before any work."""
    from moegs.device import resolve_device

    try:
        return resolve_device(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_device_argument(parser: argparse.ArgumentParser, what: str = "train and evaluate") -> None:
    """``--device`` of a command that computes with torch."""
    parser.add_argument(
        "--device",
        type=device,
        default="auto",
        help=f"where to {what}: auto (a GPU when torch sees one, else the CPU), cpu, cuda or cuda:<index>",
    )


def scene_name(text: str) -> str:
    """argparse type: ``<dataset>:<scene>`` with a registered dataset (the folder is looked up later)."""
    from moegs.data import parse_scene_name

    try:
        parse_scene_name(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def frame_window(text: str) -> tuple[int, int]:
    """argparse type: ``START:STOP``, integers with 0 <= START < STOP."""
    start, sep, stop = text.partition(":")
    try:
        window = (int(start), int(stop))
    except ValueError:
        window = None
    if not sep or window is None or not 0 <= window[0] < window[1]:
        raise argparse.ArgumentTypeError(f"expected START:STOP with 0 <= START < STOP, got {text!r}")
    return window
