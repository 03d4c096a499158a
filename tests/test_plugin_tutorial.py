"""The README's "Add your own expert", run as written: the tutorial's module becomes an installed
package with a ``moegs.experts`` entry point (a ``.dist-info`` folder on the path, which is what pip
writes), then the plugin is listed, passes the expert protocol, trains, routes with a built-in expert and
lands in Table X's LaTeX and report through ``--candidate``, with no edit inside ``moegs/`` or ``bench/``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers.protocol import build, check_protocol

import moegs.experts
from moegs.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"
SCENE = "synthetic:dnerf_like"


def tutorial_block(marker: str) -> str:
    """The fenced code block after ``<!-- tutorial:<marker> -->`` in the README."""
    match = re.search(rf"<!-- tutorial:{marker} -->\s*```\w*\n(.*?)```", README.read_text(), re.S)
    assert match, f"README has no tutorial block {marker!r}"
    return match.group(1)


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The tutorial installed as the distribution ``moegs-linear`` in a folder on ``sys.path`` (and on
    ``PYTHONPATH`` for the commands' worker processes)."""
    site = tmp_path_factory.mktemp("site")
    (site / "moegs_linear").mkdir()
    (site / "moegs_linear" / "__init__.py").write_text(tutorial_block("expert"))
    entry = re.search(r'^(\w+) = "([\w.:]+)"$', tutorial_block("entry-point"), re.M)
    dist = site / "moegs_linear-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: moegs-linear\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[moegs.experts]\n{entry.group(1)} = {entry.group(2)}\n")
    sys.path.insert(0, str(site))
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), old]))
    moegs.experts.reload_plugins()
    yield site
    sys.path.remove(str(site))
    if old is None:
        del os.environ["PYTHONPATH"]
    else:
        os.environ["PYTHONPATH"] = old
    moegs.experts.reload_plugins()


def test_plugin_is_listed_and_follows_the_protocol(plugin, tmp_path, capsys):
    assert main(["list"]) == 0
    assert "linear       plugin expert from moegs-linear" in capsys.readouterr().out
    check_protocol("linear", tmp_path)
    expert, scene = build("linear")  # the velocities move the Gaussians and learn
    expert.splats["velocity"].data.fill_(0.1)
    assert not torch.equal(expert.frame(0.0).means, expert.frame(1.0).means)
    expert.render(scene.train[0].camera, scene.background)[0].mean().backward()
    assert bool(expert.splats["velocity"].grad.abs().sum() > 0)


@pytest.mark.slow
def test_plugin_trains_and_routes(plugin, tmp_path, capsys):
    for name in ("linear", "static"):
        argv = ["train", "--expert", name, "--scene", SCENE, "--iterations", "40", "--quiet"]
        assert main([*argv, "--out", str(tmp_path / name)]) == 0
    argv = ["route", "--experts", "linear,static", "--scene", SCENE, "--out", str(tmp_path)]
    assert main([*argv, "--iterations", "20", "--gate-views", "1", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "expert linear" in captured.out
    assert (tmp_path / "router_vapr" / "gates" / "gate_0_linear_000.png").is_file()
    for name in ("linear", "static"):  # trained with --iterations 40, not the quick preset's: said so
        assert f"reusing {tmp_path / name}, a finished run of another config" in captured.err


@pytest.mark.slow
def test_plugin_is_a_table_x_candidate(plugin, tmp_path):
    cmd = [sys.executable, "-m", "bench.all", "--tables", "10", "--candidate", "linear", "--preset", "tiny"]
    cmd += ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out"), "--no-progress"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    subset = tmp_path / "out" / "reports" / "subsets" / "tiny-tab10"
    latex = (subset / "tables" / "tab10.tex").read_text()
    row = next(line for line in latex.splitlines() if line.startswith(r"+ linear"))
    assert re.search(r"\d+\.\d+", row), row  # our number is in the table
    report = (subset / "reports" / "REPORT.md").read_text()
    assert "N=3 with candidate 'linear' improves over N=2" in report


BROKEN_PLUGINS = {  # entry point value, module source, expected message after "expert 'bad' (...)"
    "cannot import": ("nosuch_module_xyz:Expert", None, "cannot import nosuch_module_xyz"),
    "no such class": ("badplugin:Missing", "X = 1\n", "module badplugin has no 'Missing'"),
    "not an expert": ("badplugin:X", "X = 1\n", "1 is not a subclass of moegs.experts.base.Expert"),
    "wrong name": (
        "badplugin:Other",
        "from moegs.experts.static import StaticExpert\nclass Other(StaticExpert):\n    name = 'other'\n",
        "the class sets name = 'other'; it must be 'bad'",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN_PLUGINS))
def test_broken_plugins_are_named(case, tmp_path, monkeypatch):
    value, source, message = BROKEN_PLUGINS[case]
    dist = tmp_path / "badplugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: badplugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[moegs.experts]\nbad = {value}\n")
    if source is not None:
        (tmp_path / "badplugin.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("badplugin", None)
    moegs.experts.reload_plugins()
    try:
        assert "bad" in [s.name for s in moegs.experts.list_experts()]
        with pytest.raises((ImportError, ValueError)) as err:
            moegs.experts.get_expert_class("bad")
        assert str(err.value).startswith(
            f"expert 'bad' (entry point 'bad' = '{value}' of badplugin): {message}"
        )
    finally:
        monkeypatch.undo()
        moegs.experts.reload_plugins()


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("static = moegs.experts.static:StaticExpert", "'static' is the name of a built-in expert"),
        ("bad = badplugin", "expected 'package.module:ExpertClass'"),
    ],
)
def test_bad_entry_points_are_named(line, message, tmp_path, monkeypatch):
    dist = tmp_path / "badplugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: badplugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[moegs.experts]\n{line}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    moegs.experts.reload_plugins()
    try:
        with pytest.raises(ValueError, match=re.escape(message)) as err:
            moegs.experts.list_experts()
        assert "of badplugin" in str(err.value)
    finally:
        monkeypatch.undo()
        moegs.experts.reload_plugins()


def test_candidate_by_class_path_reaches_the_workers(tmp_path, monkeypatch):
    """``--candidate package.module:Class`` registers an unpackaged expert for the run and its workers."""
    from bench.all import register_candidate

    source = tutorial_block("expert").replace('name = "linear"', 'name = "loose"')
    (tmp_path / "loose_expert.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("MOEGS_EXPERTS", "")
    try:
        assert register_candidate("loose_expert:LinearMotionExpert") == "loose"
        assert os.environ["MOEGS_EXPERTS"] == "loose=loose_expert:LinearMotionExpert"
        assert moegs.experts.get_spec("loose").plugin == "$MOEGS_EXPERTS"
        code = "import moegs.experts as e; print(e.get_spec('loose').target)"
        env = {**os.environ, "PYTHONPATH": str(tmp_path)}
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
        )
        assert out.stdout.strip() == "loose_expert:LinearMotionExpert"
    finally:
        monkeypatch.undo()
        moegs.experts.reload_plugins()


def test_listing_experts_does_not_import_torch():
    code = "import sys, moegs.experts as e; e.list_experts(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
