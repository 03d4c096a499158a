"""The command line's argument types: each accepts its whole range, bounds included where the range says
so, and refuses the rest (NaN and infinity too) with what it expected and what it got."""

from __future__ import annotations

import argparse
import re

import pytest

from moegs.cli_types import (
    frame_window,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    seed,
    unit_scale,
    unit_time,
)


@pytest.mark.parametrize(
    ("parse", "accepted", "refused"),
    [
        (positive_int, ["1", "7"], ["0", "-1", "1.5", "x"]),
        (non_negative_int, ["0", "3"], ["-1", "x"]),
        (positive_float, ["1e-9", "2.5"], ["0", "-1", "nan", "inf", "x"]),
        (non_negative_float, ["0", "2.5"], ["-0.1", "nan", "inf", "x"]),
        (seed, ["0", str(2**63 - 1)], ["-1", str(2**63), "1e3"]),
        (unit_time, ["0", "0.5", "1"], ["-0.1", "1.0001", "nan"]),
        (unit_scale, ["1", "0.125"], ["0", "1.5", "nan"]),
    ],
    ids=[
        "positive_int",
        "non_negative_int",
        "positive_float",
        "non_negative_float",
        "seed",
        "unit_time",
        "unit_scale",
    ],
)
def test_each_type_accepts_its_range_and_refuses_the_rest(parse, accepted, refused):
    for text in accepted:
        parse(text)
    for text in refused:
        with pytest.raises(argparse.ArgumentTypeError, match=rf"^expected .*, got '{re.escape(text)}'$"):
            parse(text)


def test_a_frame_window_is_non_empty_and_starts_at_zero_or_later():
    assert frame_window("0:3") == (0, 3) and frame_window("5:6") == (5, 6)
    for text in ("3:3", "3:2", "-1:2", "3", "a:b", ":4"):
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(f"got '{text}'")):
            frame_window(text)
