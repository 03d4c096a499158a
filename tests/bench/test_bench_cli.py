"""The bench commands refuse bad arguments before any work: one message naming the argument."""

from __future__ import annotations

import pytest

from bench.all import main

TAB17 = ["--quick", "--tables", "17", "--no-run", "--no-progress"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--jobs", "0"], "argument --jobs: expected a positive integer, got '0'"),
        (["--jobs", "two"], "argument --jobs: expected a positive integer, got 'two'"),
        (["--timeout", "-1"], "argument --timeout: expected a positive number, got '-1'"),
        (["--timeout", "nan"], "argument --timeout: expected a positive number, got 'nan'"),
        (["--timeout", "inf"], "argument --timeout: expected a positive number, got 'inf'"),
        (["--slurm-time", "0"], "argument --slurm-time: expected a positive integer, got '0'"),
        (["--slurm-gpus", "-1"], "argument --slurm-gpus: expected an integer >= 0, got '-1'"),
        (["--slurm-cpus", "0"], "argument --slurm-cpus: expected a positive integer, got '0'"),
        (["--preset", "huge"], "argument --preset: invalid choice: 'huge'"),
    ],
)
def test_bad_values_are_rejected_by_the_parser(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([*TAB17, *argv])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--workspace", "--out"])
@pytest.mark.parametrize("below", ["", "sub/folder"])
def test_a_file_where_a_folder_belongs_is_named(flag, below, tmp_path, capsys):
    (tmp_path / "a-file").write_text("x")
    folder = tmp_path / "a-file" / below
    other = "--out" if flag == "--workspace" else "--workspace"
    assert main([*TAB17, flag, str(folder), other, str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err
    assert f"error: {flag} {folder}: {tmp_path / 'a-file'} is a file; expected a folder" in err


def test_unknown_tables_and_candidates_list_the_valid_names(tmp_path, capsys):
    out = ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]
    assert main(["--quick", "--tables", "42", *out]) == 2
    assert "unknown table/figure id '42'; valid ids: tab01, tab02" in capsys.readouterr().err
    assert main(["--quick", "--tables", "10", "--candidate", "nope", "--no-run", *out]) == 2
    assert "--candidate: unknown expert 'nope'; registered experts: deformable" in capsys.readouterr().err
    assert main(["--quick", "--tables", "3", "--candidate", "static", "--no-run", *out]) == 2
    assert "error: --candidate extends tab10: select it with --tables" in capsys.readouterr().err


def test_spec_modules_are_data_and_table_x_declares_its_extension():
    """No spec imports the driver or runs as a script; Table X extends itself with candidate rows."""
    import ast
    from pathlib import Path

    from bench.registry import get_spec, list_specs

    for spec_id in list_specs("tables"):
        source = (Path(__file__).parents[2] / "bench" / f"{spec_id}.py").read_text()
        imported = {n.module or "" for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ImportFrom)} | {
            a.name for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Import) for a in n.names
        }
        assert not {m for m in imported if m.startswith("bench.") and m != "bench.spec"}, spec_id
        assert "__main__" not in source, spec_id
    tab10 = get_spec("10")
    assert [s for s in list_specs() if get_spec(s).candidates is not None] == ["tab10"]
    extended = tab10.candidates(tab10, ("linear",))
    assert extended.rows[-1].name == "+ linear" and extended.claims[-1].id == "n3-beats-n2-candidate-linear"
    assert extended.candidates is tab10.candidates and len(extended.rows) == len(tab10.rows) + 1


@pytest.mark.parametrize(
    ("module", "argv", "message"),
    [
        (
            "profile",
            ["--expert", "static", "--scene", "dnerf:mutant", "--steps", "0"],
            "--steps: expected a positive integer",
        ),
        (
            "profile",
            ["--expert", "static", "--scene", "dnerf:mutant", "--seed", "-1"],
            "--seed: expected an integer seed",
        ),
        ("single_pass", ["--rounds", "0"], "--rounds: expected a positive integer, got '0'"),
        ("single_pass", ["--warmup", "-1"], "--warmup: expected an integer >= 0, got '-1'"),
        ("moe_fps", ["--views", "0"], "--views: expected a positive integer, got '0'"),
        ("moe_fps", ["--scale", "0"], "--scale: expected a positive number, got '0'"),
        ("regress", ["--time", "-1"], "--time: expected a number >= 0, got '-1'"),
    ],
)
def test_the_other_bench_tools_check_their_numbers(module, argv, message, capsys):
    import importlib

    with pytest.raises(SystemExit) as exit_info:
        importlib.import_module(f"bench.{module}").main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_the_executor_gets_the_jobs_timeout_and_slurm_settings(monkeypatch):
    import bench.executors
    from bench.all import _executor, build_parser

    made = []
    monkeypatch.setattr(bench.executors, "make_executor", lambda kind, **kwargs: made.append((kind, kwargs)))
    argv = ["--jobs", "3", "--timeout", "90", "--slurm-time", "30", "--slurm-cpus", "4", "--slurm-gpus", "1"]
    _executor(build_parser().parse_args(argv))
    ((kind, kwargs),) = made
    assert kwargs["jobs"] == 3 and kwargs["timeout"] == 90.0 and kwargs["threads"] == 4
    assert kwargs["parameters"] == {"timeout_min": 30, "cpus_per_task": 4, "gpus_per_node": 1}
