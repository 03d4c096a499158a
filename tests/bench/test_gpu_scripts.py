"""``bench/gpu``: the device scripts parse and name only tests and modules that exist."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
from pathlib import Path

import pytest

GPU = Path(__file__).resolve().parents[2] / "bench" / "gpu"
REPO = GPU.parents[1]


@pytest.mark.parametrize("script", ["prepare.sh", "check.sh"])
def test_scripts_parse(script):
    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("no bash")
    subprocess.run([bash, "-n", str(GPU / script)], check=True)


def test_check_names_existing_tests_and_modules():
    text = (GPU / "check.sh").read_text()
    paths = re.findall(r"\btests/[\w/]+\.py", text)
    modules = set(re.findall(r"python3 -m ((?:bench|moegs)\.[\w.]+)", text))
    assert paths and modules >= {"bench.single_pass", "bench.rasterizer", "bench.moe_fps", "moegs.kernels"}
    assert [p for p in paths if not (REPO / p).is_file()] == []
    assert [m for m in modules if importlib.util.find_spec(m) is None] == []
