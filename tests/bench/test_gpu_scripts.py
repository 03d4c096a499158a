"""``bench/gpu``: the device scripts parse, name only tests and modules that exist, and write at most the 8
files a lent machine sends back."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
from pathlib import Path

import pytest

GPU = Path(__file__).resolve().parents[2] / "bench" / "gpu"
REPO = GPU.parents[1]
MAX_OUT_FILES = 8  # what comes back from a lent machine's $OUT


@pytest.mark.parametrize("script", ["prepare.sh", "check.sh", "train_check.sh"])
def test_scripts_parse(script):
    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("no bash")
    subprocess.run([bash, "-n", str(GPU / script)], check=True)


def modules(text: str) -> set[str]:
    return set(re.findall(r"python3? -m ((?:bench|moegs)\.[\w.]+)", text))


def test_check_names_existing_tests_and_modules():
    text = (GPU / "check.sh").read_text()
    paths = re.findall(r"\btests/[\w/]+\.py", text)
    expected = {"bench.single_pass", "bench.rasterizer", "bench.moe_fps", "moegs.kernels"}
    assert paths and modules(text) >= expected
    assert [p for p in paths if not (REPO / p).is_file()] == []
    assert [m for m in modules(text) if importlib.util.find_spec(m) is None] == []


def test_train_check_names_existing_modules_and_reads_what_prepare_stages():
    text, prepare = (GPU / "train_check.sh").read_text(), (GPU / "prepare.sh").read_text()
    assert modules(text) == {"bench.gpu_train", "moegs.kernels"} and modules(prepare) == {"bench.gpu_train"}
    assert [m for m in modules(text) if importlib.util.find_spec(m) is None] == []
    assert 'MOEGS_DATA="$PWD/.gpu/data"' in text and ".gpu/data/dnerf/mutant" in prepare
    assert "--stage-dnerf" in prepare and "--device cuda" in text


def out_files(text: str) -> set[str]:
    """The files a script writes under ``$out``, with ``for x in a b`` loops' values put in."""
    loops = dict(re.findall(r"for (\w+) in ([\w ]+); do", text))
    names: set[str] = set()
    for name in re.findall(r"\$out/([\w.$-]+)", text):
        var = re.search(r"\$(\w+)", name)
        values = loops.get(var.group(1), "").split() if var else [""]
        names |= {name.replace(var.group(0), v) if var else name for v in values}
    return names


@pytest.mark.parametrize("script", ["check.sh", "train_check.sh"])
def test_scripts_write_at_most_eight_files(script):
    files = out_files((GPU / script).read_text())
    assert 1 <= len(files) <= MAX_OUT_FILES, sorted(files)
    assert all(re.fullmatch(r"[\w.-]+", f) for f in files), sorted(files)  # names the transfer accepts


def test_out_files_expands_loops():
    text = 'for run in 1 2; do\n  x --json "$out/a_run$run.json"\ndone\ncp b "$out/b.json"\nlog="$out/c.log"'
    assert out_files(text) == {"a_run1.json", "a_run2.json", "b.json", "c.log"}
