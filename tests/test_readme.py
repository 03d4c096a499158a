"""The README as a new user reads it: short, free of lab notes, and every code block in it tested.

Each fenced block follows a marker ``<!-- readme: KIND -->`` saying how it is tested:

* ``ci-main`` / ``ci-test``: the set-up lines of a fresh machine; ``ci-test`` is what ``.ci/run`` runs,
  ``ci-main`` the same with the quick run instead of the tests (planned here with ``--dry-run``);
* ``run``: executed as written, in order, in a scratch folder on real ``mutant`` (the new user's path:
  a tiny table and its report, train, eval, render, export, route);
* ``plan``: ``bench.all`` commands, run with ``--dry-run`` (they train for hours);
* ``gpu``: needs CUDA: checked against the package's extras and the command line's parser;
* ``plugin``: a block of ``docs/plugins.md``, which ``tests/test_plugin_tutorial.py`` runs as written;
* ``cite``: the BibTeX entry, checked against the paper's title.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
MARKED = re.compile(r"<!-- readme: ([\w-]+) -->\n```(\w*)\n(.*?)```", re.S)
KINDS = {"ci-main", "ci-test", "run", "plan", "gpu", "plugin", "cite"}


def blocks(kind: str | None = None) -> list[str]:
    """The README's code blocks of ``kind`` (all marked blocks when None), in order."""
    return [body for k, _, body in MARKED.findall(README.read_text()) if kind in (None, k)]


def commands(block: str) -> list[str]:
    """The shell commands of a block: one per line, ``&&`` chains split."""
    return [c.strip() for line in block.splitlines() if line.strip() for c in line.split(" && ")]


def test_readme_is_short_and_holds_no_lab_notes():
    text = README.read_text()
    assert len(text.splitlines()) <= 300
    for word in ("EPYC", "Xeon", " VM", "issue "):
        assert word not in text, f"README mentions {word.strip()!r}: measurement notes belong in docs/"
    assert not re.findall(r"\b20\d\d-\d\d-\d\d\b", text), "dates belong in docs/ or bench/RUNS.md"
    hashes = [
        h for h in re.findall(r"\b[0-9a-f]{7,40}\b", text) if re.search(r"\d", h) and re.search("[a-f]", h)
    ]
    assert not hashes, f"commit hashes in the README: {hashes}"


def test_every_code_block_is_marked_with_how_it_is_tested():
    text = README.read_text()
    fences = len(re.findall(r"^```", text, re.M))
    marked = MARKED.findall(text)
    assert fences % 2 == 0 and len(marked) == fences // 2, "a README code block has no <!-- readme: KIND -->"
    assert {k for k, _, _ in marked} <= KINDS


def test_set_up_commands_are_what_ci_runs():
    [main], [tests] = blocks("ci-main"), blocks("ci-test")
    main_steps, test_steps = commands(main), commands(tests)
    assert main_steps[:-1] == test_steps[:-1]
    assert (main_steps[-1], test_steps[-1]) == ("python -m bench.all --quick", "python -m pytest")
    ci = (REPO / ".ci" / "run").read_text()
    ci_lines = [re.sub(r"^python -m | --quiet", "", line.strip()) for line in ci.splitlines()]
    for step in test_steps[2:]:  # after creating and activating the venv (.ci/run uses a temporary one)
        assert re.sub(r"^python -m ", "", step) in ci_lines, f".ci/run does not run {step!r}"
    assert "python -m venv" in test_steps[0].replace("python3.11", "python") and "activate" in test_steps[1]


def _bench_dry_run(command: str, tmp_path: Path) -> str:
    argv = shlex.split(command)
    assert argv[:3] == ["python", "-m", "bench.all"], command
    if "--dry-run" not in argv:
        argv.append("--dry-run")
    env = {**os.environ, "MOEGS_BENCH_DIR": str(tmp_path / "ws")}
    done = subprocess.run(
        [sys.executable, *argv[1:]], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, f"{command}: {done.stderr[-2000:]}"
    return done.stdout


def test_plan_blocks_plan(tmp_path):
    planned = [c for b in blocks("plan") for c in commands(b)] + commands(blocks("ci-main")[0])[-1:]
    assert planned
    for command in planned:
        out = _bench_dry_run(command, tmp_path)
        assert "total" in out and "H100-h" in out, out[-1000:]


def test_gpu_block_names_real_extras_and_arguments():
    from moegs.cli import build_parser

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for command in commands("\n".join(blocks("gpu"))):
        argv = shlex.split(command)
        if argv[:2] == ["pip", "install"]:
            extra = re.fullmatch(r"-e|\.\[(\w+)\]", argv[-1])
            assert extra and extra[1] in extras and any("gsplat" in d for d in extras[extra[1]])
        else:  # parsed with --device cpu: the parser refuses a device this machine lacks
            assert argv[0] == "moegs" and argv[argv.index("--device") + 1] == "cuda"
            argv[argv.index("--device") + 1] = "cpu"
            assert build_parser().parse_args(argv[1:]).command == argv[1]


def test_plugin_blocks_are_those_the_tutorial_runs():
    tutorial = (REPO / "docs" / "plugins.md").read_text()
    assert blocks("plugin")
    for block in blocks("plugin"):
        assert f"\n{block}```" in tutorial, f"README plugin block not in docs/plugins.md:\n{block}"


def test_citation_names_the_paper():
    [bib] = blocks("cite")
    paper = REPO.parent / "shared" / "paper" / "moe-gs-mode.tex"
    assert "@article{" in bib and "On the Design of Mixture-of-Experts for Dynamic Gaussian Splatting" in bib
    if paper.is_file():
        assert "Jin, In-Hwan" in bib and "In-Hwan Jin" in paper.read_text()


def test_a_new_user_follows_the_readme(tmp_path, mutant_root):
    """Every ``run`` block as written, in order, in a scratch folder; then the files the README promises."""
    env = {
        **os.environ,
        "BROWSER": "true",  # webbrowser.open runs `true <url>`: no window in a test
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
    }
    env.pop("MOEGS_BENCH_DIR", None)
    for command in (c for b in blocks("run") for c in commands(b)):
        done = subprocess.run(command, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True)
        assert done.returncode == 0, f"{command}:\n{done.stdout[-1500:]}\n{done.stderr[-1500:]}"
    report = tmp_path / "reports/subsets/tiny-tab17/reports"
    assert (
        "Table XVII" in (report / "REPORT.html").read_text()
        or "tab17" in (report / "REPORT.html").read_text()
    )
    run = tmp_path / "runs/grid4d"
    for name in (
        "config.json",
        "checkpoint.safetensors",
        "metrics.json",
        "loss.json",
        "loss.png",
        "eval-moegs.json",
        "renders/video.mp4",
        "renders/psnr.csv",
        "point_cloud_t0.500.ply",
    ):
        assert (run / name).is_file(), f"README promises {run / name}"
    assert (tmp_path / "runs/moe").is_dir() and list((tmp_path / "runs/moe").rglob("*.png"))
