"""``docs/plugins.md``, "Add your own expert", run as written.

Every fenced block of the page follows a marker ``<!-- tutorial: KIND [PATH] -->``: ``file PATH`` blocks are
written to ``PATH``, ``run`` blocks run in bash, in page order, in an empty folder, and each ``output``
block's lines must be lines of the previous ``run`` block's output. The page's ``pip install -e`` runs in a
virtual environment layered over this one (it sees moegs and torch; pip may not reach an index), so the
plugin is installed as a user installs it and this environment is left alone. The in-process tests build
the same package as an installed distribution (a ``.dist-info`` folder on the path, which is what pip
writes): the plugin is listed, passes the expert protocol, agrees with Grid4D on the background and lands
in Table X's LaTeX and report through ``--candidate``, with no edit inside ``moegs/`` or ``bench/``.
"""

from __future__ import annotations

import hashlib
import os
import re
import shlex
import site
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from helpers.protocol import build, check_protocol

import moegs.experts
from moegs.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "plugins.md"
SCENE = "synthetic:dnerf_like"
MARKED = re.compile(r"<!-- tutorial: (file|run|output)(?: (\S+))? -->\n```(\w*)\n(.*?)```", re.S)
PYPROJECT, MODULE = "moegs-linear/pyproject.toml", "moegs-linear/moegs_linear.py"


@dataclass(frozen=True)
class Block:
    kind: str
    """``file``, ``run`` or ``output``."""
    path: str
    """Where a ``file`` block goes ("" for the others)."""
    language: str
    body: str


def page_blocks() -> list[Block]:
    """The page's marked code blocks, in order."""
    return [Block(*m) for m in MARKED.findall(PAGE.read_text())]


def page_file(path: str) -> str:
    """The body of the page's ``file`` block for ``path``."""
    [body] = [b.body for b in page_blocks() if b.kind == "file" and b.path == path]
    return body


def test_every_block_of_the_page_is_run_or_checked():
    text = PAGE.read_text()
    fences = len(re.findall(r"^```", text, re.M))
    blocks = page_blocks()
    assert fences % 2 == 0 and len(blocks) == fences // 2, "a code block of docs/plugins.md has no marker"
    assert {b.path for b in blocks if b.kind == "file"} == {PYPROJECT, MODULE}
    for before, block in zip(blocks, blocks[1:], strict=False):
        assert block.kind != "output" or before.kind == "run", f"output block after a {before.kind} block"
    assert blocks[0].kind != "output"
    commands = [line for b in blocks if b.kind == "run" for line in b.body.splitlines()]
    assert any(c.startswith("moegs route --experts linear,grid4d ") for c in commands)
    assert any(c.startswith("moegs route --runs ") for c in commands)


def test_the_plugins_background_is_grid4ds():
    """The page's pyproject registers the module's class, whose config trains D-NeRF on Grid4D's
    background (the 3DGS parent's is white there), so the route on the page can blend them."""
    project = tomllib.loads(page_file(PYPROJECT))
    assert project["project"]["entry-points"]["moegs.experts"] == {
        "linear": "moegs_linear:LinearMotionExpert"
    }
    namespace: dict = {}
    exec(compile(page_file(MODULE), MODULE, "exec", dont_inherit=True), namespace)
    config = namespace["LinearMotionConfig"]
    grid4d = moegs.experts.get_expert_class("grid4d").config_class
    static = moegs.experts.get_expert_class("static").config_class
    assert static.background_for("dnerf") == "white"
    for dataset in ("dnerf", "n3v", "panoptic", "technicolor", "hypernerf"):
        assert config.background_for(dataset) == grid4d.background_for(dataset) == "black"


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The page's package installed as the distribution its pyproject names, in a folder on ``sys.path``
    (and on ``PYTHONPATH`` for the commands' worker processes)."""
    site_dir = tmp_path_factory.mktemp("site")
    project = tomllib.loads(page_file(PYPROJECT))["project"]
    (site_dir / Path(MODULE).name).write_text(page_file(MODULE))
    dist = site_dir / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n"
    )
    entries = "".join(f"{k} = {v}\n" for k, v in project["entry-points"]["moegs.experts"].items())
    (dist / "entry_points.txt").write_text(f"[moegs.experts]\n{entries}")
    sys.path.insert(0, str(site_dir))
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site_dir), old]))
    moegs.experts.reload_plugins()
    yield site_dir
    sys.path.remove(str(site_dir))
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


def layered_venv(path: Path) -> dict[str, str]:
    """A virtual environment at ``path`` whose Python also sees this environment's packages (moegs, torch),
    with ``pip`` and ``moegs`` commands: a user's environment with moegs installed, which the page's
    ``pip install -e`` changes instead of this one. Returns the environment variables of a shell in it
    (pip reads no index and builds with the setuptools present)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True, timeout=120)
    python = path / "bin" / "python"
    query = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    purelib = Path(
        subprocess.run([python, "-c", query], capture_output=True, text=True, check=True).stdout.strip()
    )
    parents = "; ".join(f"site.addsitedir({d!r})" for d in site.getsitepackages())
    (purelib / "_moegs_test_parent.pth").write_text(f"import site; {parents}\n")
    for command, module in (("pip", "pip._internal.cli.main"), ("moegs", "moegs.cli")):
        script = path / "bin" / command  # what pip writes for a console script
        script.write_text(f"#!{python}\nimport sys\nfrom {module} import main\nsys.exit(main())\n")
        script.chmod(0o755)
    drop = ("PIP_", "PYTHONPATH", "VIRTUAL_ENV", moegs.experts.EXPERTS_ENV)
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    return env | {
        "PATH": f"{path / 'bin'}{os.pathsep}{os.environ['PATH']}",
        "VIRTUAL_ENV": str(path),
        "PYTHONPATH": str(ROOT),
        "PIP_NO_INDEX": "1",
        "PIP_NO_BUILD_ISOLATION": "0",  # pip's spelling of --no-build-isolation
        "PIP_DISABLE_PIP_VERSION_CHECK": "1",
        "PIP_CONFIG_FILE": os.devnull,
    }


def routed_runs(command: str) -> list[str]:
    """The run folders of a ``moegs route --runs`` command (none for other commands)."""
    argv = shlex.split(command)
    if argv[:2] != ["moegs", "route"] or "--runs" not in argv:
        return []
    rest = argv[argv.index("--runs") + 1 :]
    return rest[: next((i for i, a in enumerate(rest) if a.startswith("--")), len(rest))]


def snapshot(folder: Path) -> dict[str, tuple[int, str]]:
    """Each file under ``folder``: its modification time and content hash."""
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.slow
def test_the_page_runs_as_written(tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    env = layered_venv(tmp_path / "venv")
    output = ""
    for block in page_blocks():
        if block.kind == "file":
            (work / block.path).parent.mkdir(parents=True, exist_ok=True)
            (work / block.path).write_text(block.body)
        elif block.kind == "run":  # command by command, as a user types them
            output = ""
            for command in filter(None, block.body.splitlines()):
                reused = {folder: snapshot(work / folder) for folder in routed_runs(command)}
                done = subprocess.run(
                    ["bash", "-euo", "pipefail", "-c", command],
                    cwd=work,
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=1200,
                )
                assert done.returncode == 0, f"{command}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
                assert "Traceback" not in done.stderr, done.stderr[-3000:]
                output += done.stdout
                for folder, files in reused.items():  # --runs trains nothing: the runs are left alone
                    assert files and snapshot(work / folder) == files, folder
                    assert f": reusing the trained run {folder} (" in done.stdout
        else:
            lines = output.splitlines()
            for line in block.body.splitlines():
                assert line in lines, f"{line!r} not in the output:\n{output[-3000:]}"

    moe = work / "runs" / "moe"  # --experts trained both experts and the router there
    assert sorted(p.name for p in moe.iterdir()) == ["grid4d", "linear", "router_vapr"]
    assert (moe / "router_vapr" / "gates" / "gate_0_linear_000.png").is_file()
    routed = work / "runs" / "moe-s1"  # --runs: the router alone
    assert [p.name for p in routed.iterdir()] == ["router_vapr"]
    assert "MoE-GS (vapr router) on synthetic:dnerf_like" in output


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

    source = page_file(MODULE).replace('name = "linear"', 'name = "loose"')
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
