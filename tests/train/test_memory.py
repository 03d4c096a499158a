"""keep_freed_memory: glibc accepts the settings; the environment switch leaves malloc alone."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys

import pytest

from moegs.train.memory import ENV, keep_freed_memory


def _glibc() -> bool:
    try:
        return hasattr(ctypes.CDLL(None), "gnu_get_libc_version")
    except OSError:
        return False


def _run_in_fresh_process(env_value: str | None) -> str:
    code = "from moegs.train.memory import keep_freed_memory; print(keep_freed_memory())"
    env = None if env_value is None else {**os.environ, ENV: env_value}
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout


@pytest.mark.skipif(not (sys.platform.startswith("linux") and _glibc()), reason="needs Linux with glibc")
def test_glibc_accepts_the_settings_and_the_switch_turns_them_off(monkeypatch):
    assert keep_freed_memory() is True
    monkeypatch.delenv(ENV, raising=False)
    assert _run_in_fresh_process(None).strip() == "True"
    assert _run_in_fresh_process("0").strip() == "False"
