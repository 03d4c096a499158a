"""``tox list`` shows the environments a user needs and no phantom one: a value's continuation line that
begins with ``word:`` is a factor condition to tox, which then lists ``word`` as an environment running
the base ``[testenv]`` (the whole test suite); ``tox.ini`` had one (``Preset:``)."""

from __future__ import annotations

import configparser
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

TOX_INI = Path(__file__).resolve().parents[1] / "tox.ini"
EXPECTED = {
    "test",
    "lint",
    "bench",
    "bench-compare",
    "docs",
    "repro-all",
    *(f"repro-tab{n}" for n in range(1, 20)),
}
FACTOR_LINE = re.compile(r"^!?[\w.*?\[\]{},-]+:\s")  # tox's factor condition: ``py311,lint: value``


def test_no_continuation_line_reads_as_a_factor_condition():
    config = configparser.ConfigParser(interpolation=None)
    config.read(TOX_INI, encoding="utf-8")
    wrong = [
        f"[{section}] {key}: {line.strip()!r}"
        for section in config.sections()
        for key, value in config[section].items()
        for line in value.splitlines()[1:]
        if FACTOR_LINE.match(line.strip())
    ]
    assert not wrong, "continuation lines tox reads as factor conditions: " + "; ".join(wrong)


def test_tox_lists_the_environments_a_user_needs():
    if importlib.util.find_spec("tox") is None:
        pytest.skip("tox is not installed (pip install tox, or '.[dev]')")
    listed = subprocess.run(
        [sys.executable, "-m", "tox", "list", "-c", str(TOX_INI)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        cwd=TOX_INI.parent,
    ).stdout
    names = {line.split(" -> ")[0].strip() for line in listed.splitlines() if " -> " in line}
    assert names == EXPECTED, f"unexpected: {sorted(names - EXPECTED)}, missing: {sorted(EXPECTED - names)}"
