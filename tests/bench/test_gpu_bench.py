"""The bench on GPUs, checked without one: the device kind is part of every key; ``--gpus`` gives each local
worker one GPU through ``CUDA_VISIBLE_DEVICES``, round robin; a device the machine lacks is one line before
any work; Slurm reserves the GPU the tasks use and can pack tasks into one job; ``--dry-run`` plans and
estimates without running; the cells copy tensors to the host before ``.numpy()``."""

from __future__ import annotations

import ast
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

import bench.executors
import bench.runner
from bench.all import build_parser, choose_device, main
from bench.cells import scene as scene_kind
from bench.estimate import ROUTER_FACTOR, Work, gpu_seconds, work_of
from bench.executors import LocalExecutor, SubmititExecutor
from bench.plan import make_plan
from bench.presets import get_preset
from bench.runlog import record_run, took
from bench.tasks import Task
from bench.worker import run_jobs

CELLS = Path(__file__).resolve().parents[2] / "bench" / "cells"


def _task(device: str = "cpu") -> Task:
    params = {"expert": "deformable", "dataset": "dnerf"}
    return Task("build", "expert", params, "dnerf:mutant", {"resolution_scale": 0.125}, "tiny", 0, device)


# ------------------------------------------------------------------------------------------ keys
def test_the_device_kind_is_part_of_the_key_and_derived_tasks_keep_it():
    cpu, cuda = _task("cpu"), _task("cuda")
    assert cpu.key != cuda.key and cpu.identity()["device"] == "cpu" and cuda.identity()["device"] == "cuda"
    derived = cuda.derive("eval", "expert", dict(cuda.params))
    assert derived.device == "cuda" and scene_kind.task_for(cuda).device == "cuda"
    assert Task.from_dict(cuda.to_dict()) == cuda
    legacy = {k: v for k, v in cpu.to_dict().items() if k != "device"}  # a job file from before devices
    assert Task.from_dict(legacy) == cpu
    with pytest.raises(ValueError, match=r"Task.device must be one of \('cpu', 'cuda'\), got 'cuda:0'"):
        _task("cuda:0")


def test_a_cuda_plan_has_every_task_on_cuda():
    plan = make_plan(["tab17"], get_preset("tiny"), "cuda")
    tasks = [*plan.eval_tasks(), *(t for level in plan.build_levels() for t in level)]
    assert plan.device == "cuda" and tasks and {t.device for t in tasks} == {"cuda"}
    cpu_keys = {t.key for t in make_plan(["tab17"], get_preset("tiny")).eval_tasks()}
    assert not cpu_keys & {t.key for t in plan.eval_tasks()}


# ------------------------------------------------------------------------------------ local GPUs
class _Proc:
    """A ``subprocess.Popen`` stand-in that records the worker's environment and exits 0."""

    started: list[str] = []
    gate: threading.Event | None = None

    def __init__(self, argv, stdout, stderr, env, cwd, **popen_options):
        type(self).started.append(env.get("CUDA_VISIBLE_DEVICES", "-"))
        self.env = env

    def wait(self, timeout=None):
        if type(self).gate is not None:
            type(self).gate.wait(10)
        return 0


@pytest.fixture
def popen(tmp_path, monkeypatch):
    """``Popen`` recorded; job files and logs under ``tmp_path``."""
    _Proc.started, _Proc.gate = [], None
    monkeypatch.setattr(bench.executors.subprocess, "Popen", _Proc)
    monkeypatch.setattr(bench.executors, "write_job", lambda ws, task, threads: tmp_path / "job.json")
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    workspace = SimpleNamespace(log_path=lambda t: tmp_path / "logs" / f"{t.key}.log")
    return workspace


def _tasks(n: int) -> list[SimpleNamespace]:
    return [SimpleNamespace(key=f"k{i}", slug=f"task-{i}") for i in range(n)]


def test_gpus_give_each_worker_one_visible_gpu_round_robin(popen, monkeypatch):
    monkeypatch.setattr(bench.executors.os, "cpu_count", lambda: 16)
    executor = LocalExecutor(gpus=[0, 1], jobs_per_gpu=2)
    assert executor.capacity == 4 and executor.threads == 4  # cores / workers
    try:
        for task in _tasks(5):  # one after another: the freed GPU goes to the back of the queue
            assert executor.submit(task, popen).result(timeout=30).ok
    finally:
        executor.close()
    assert _Proc.started == ["0", "1", "0", "1", "0"]


def test_concurrent_workers_share_the_gpus_evenly(popen):
    _Proc.gate = threading.Event()
    executor = LocalExecutor(gpus=[0, 1, 2], jobs_per_gpu=2)
    futures = [executor.submit(t, popen) for t in _tasks(6)]
    try:
        for _ in range(200):
            if len(_Proc.started) == 6:
                break
            threading.Event().wait(0.05)
        _Proc.gate.set()
        assert all(f.result(timeout=30).ok for f in futures)
    finally:
        executor.close()
    assert sorted(_Proc.started) == ["0", "0", "1", "1", "2", "2"]


def test_a_worker_gpu_is_named_as_this_process_sees_it(popen, monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")
    executor = LocalExecutor(gpus=[1])
    assert executor.worker_env(1)["CUDA_VISIBLE_DEVICES"] == "5"
    assert LocalExecutor(jobs=2).worker_env(None)["CUDA_VISIBLE_DEVICES"] == "3,5"  # no GPU: inherited
    try:
        assert executor.submit(_tasks(1)[0], popen).result(timeout=30).ok
    finally:
        executor.close()
    assert _Proc.started == ["5"]


# --------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("visible", "argv", "message"),
    [
        (
            0,
            ["--device", "cuda"],
            "error: device 'cuda': CUDA is not available here (this torch is a CPU build)",
        ),
        (0, ["--gpus", "2"], "error: --gpus 2: this machine has no GPU torch sees"),
        (1, ["--gpus", "2"], "error: --gpus 2: this machine has 1 GPU(s) (CUDA_VISIBLE_DEVICES may hide"),
        (1, ["--device", "cuda:7"], "error: device 'cuda:7': this machine has 1 GPU(s) (cuda:0 to cuda:0)"),
        (0, ["--device", "cuda:7"], "error: device 'cuda:7': CUDA is not available here"),
        (2, ["--device", "cpu", "--gpus", "1"], "error: --gpus 1 with --device cpu"),
        (0, ["--device", "gpu"], "error: device 'gpu' is not one of auto, cpu, cuda or cuda:<index>"),
        (2, ["--gpus", "0", "--device", "cuda"], "error: --gpus 0 with --device cuda: use --device cpu"),
        (2, ["--jobs", "4"], "error: --jobs with --device auto: on GPUs use --gpus and --jobs-per-gpu"),
        (0, ["--executor", "slurm", "--device", "cuda"], "error: --device cuda on Slurm needs --slurm-gpus"),
        (0, ["--executor", "slurm", "--slurm-gpus", "1", "--device", "cpu"], "error: --slurm-gpus 1 with"),
        (0, ["--executor", "slurm", "--gpus", "1"], "error: --gpus and --jobs-per-gpu are for the local"),
    ],
)
def test_a_device_the_machine_lacks_is_one_line_before_any_work(
    visible, argv, message, gpus, tmp_path, capsys
):
    gpus(visible)
    out = ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]
    assert main(["--preset", "tiny", "--tables", "17", *out, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and len(err.splitlines()) == 1
    assert not (tmp_path / "ws").exists()


@pytest.mark.parametrize(
    ("visible", "argv", "expected"),
    [
        (0, [], ("cpu", [])),
        (2, [], ("cuda", [0, 1])),
        (2, ["--gpus", "1", "--jobs-per-gpu", "3"], ("cuda", [0])),
        (2, ["--device", "cuda:1"], ("cuda", [1])),
        (2, ["--device", "cpu", "--jobs", "3"], ("cpu", [])),
        (0, ["--device", "cuda", "--no-run"], ("cuda", [])),  # rendering GPU results needs no GPU
        (0, ["--device", "cuda", "--dry-run"], ("cuda", [])),
        (0, ["--executor", "slurm", "--slurm-gpus", "1"], ("cuda", [])),
        (2, ["--executor", "slurm"], ("cpu", [])),
    ],
)
def test_the_device_and_gpus_a_command_line_asks_for(visible, argv, expected, gpus):
    gpus(visible)
    assert choose_device(build_parser().parse_args(argv)) == expected


def test_a_worker_without_the_gpu_its_task_needs_says_so():
    from bench.worker import task_device

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    assert task_device(_task("cpu")) == torch.device("cpu")
    with pytest.raises(ValueError, match="device 'cuda:0': CUDA is not available here"):
        task_device(_task("cuda"))


# ------------------------------------------------------------------------------------------- Slurm
def test_slurm_reserves_the_gpus_and_the_time_of_packed_tasks(tmp_path, monkeypatch):
    srun = tmp_path / "bin" / "srun"  # submitit's Slurm executor only checks that srun exists
    srun.parent.mkdir()
    srun.write_text("#!/bin/sh\n")
    srun.chmod(0o755)
    monkeypatch.setenv("PATH", f"{srun.parent}:{__import__('os').environ['PATH']}")
    from bench.all import _executor

    argv = ["--executor", "slurm", "--slurm-gpus", "1", "--slurm-time", "20", "--slurm-pack", "3"]
    executor = _executor(build_parser().parse_args(argv))
    assert isinstance(executor, SubmititExecutor) and executor.pack == 3
    slurm = executor.executor(SimpleNamespace(root=tmp_path / "ws"))._executor
    assert slurm.parameters["gpus_per_node"] == 1 and slurm.parameters["time"] == 60
    assert "#SBATCH --gpus-per-node=1" in slurm._make_submission_file_text("python x", "uid")
    executor.close()


class _Job:
    def __init__(self, fn, files, redirect):
        self.files = list(files)
        self.paths = SimpleNamespace(stderr="err")

    def done(self):
        return True

    def result(self):
        return ["ValueError: boom" if "k1" in f else "" for f in self.files]


class _AutoExecutor:
    jobs: list[_Job] = []

    def __init__(self, folder, cluster):
        self.parameters = {}

    def update_parameters(self, **kwargs):
        self.parameters.update(kwargs)

    def submit(self, fn, *args):
        job = _Job(fn, *args)
        type(self).jobs.append(job)
        return job


def test_packed_tasks_share_a_job_and_keep_their_own_outcomes(tmp_path, monkeypatch):
    import submitit

    _AutoExecutor.jobs = []
    monkeypatch.setattr(submitit, "AutoExecutor", _AutoExecutor)
    monkeypatch.setattr(bench.executors, "write_job", lambda ws, task, threads: tmp_path / f"{task.key}.json")
    workspace = SimpleNamespace(root=tmp_path, log_path=lambda t: tmp_path / "logs" / f"{t.key}.log")
    executor = SubmititExecutor(cluster="slurm", pack=2, pack_wait=0.2, poll_seconds=0.01)
    try:
        futures = [executor.submit(t, workspace) for t in _tasks(3)]
        outcomes = [f.result(timeout=30) for f in futures]
    finally:
        executor.close()
    assert [len(job.files) for job in _AutoExecutor.jobs] == [2, 1]  # the third waited pack_wait alone
    assert [o.ok for o in outcomes] == [True, False, True] and outcomes[1].error == "ValueError: boom"
    assert [o.task.key for o in outcomes] == ["k0", "k1", "k2"]


def test_a_packed_job_runs_its_tasks_one_after_another_past_a_failure(tmp_path, monkeypatch):
    ran = []

    def run_job(job_file, redirect=False):
        ran.append(Path(job_file).name)
        if "bad" in str(job_file):
            raise RuntimeError("cell failed\nsecond line")
        return {"status": "ok"}

    log = tmp_path / "bad.log"
    (tmp_path / "bad.json").write_text(f'{{"log": "{log}"}}')
    monkeypatch.setattr("bench.worker.run_job", run_job)
    files = [tmp_path / "a.json", tmp_path / "bad.json", tmp_path / "c.json"]
    assert run_jobs(files) == ["", "RuntimeError: cell failed", ""]
    assert ran == ["a.json", "bad.json", "c.json"] and "second line" in log.read_text()


# ----------------------------------------------------------------------------------------- dry run
def test_dry_run_prints_builds_and_hours_per_table_and_runs_nothing(tmp_path, monkeypatch, capsys):
    def never(*args, **kwargs):
        raise AssertionError("a dry run ran a task")

    monkeypatch.setattr(bench.runner, "execute", never)
    out = ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]
    assert main(["--preset", "tiny", "--tables", "17", "fig_gates_dnerf", "--dry-run", *out]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0].startswith("dry run: preset tiny, device ")
    assert "H100-h" in lines[1] and "CPU-h" in lines[1]
    assert [line.split()[0] for line in lines[2:4]] == ["tab17", "fig_gates_dnerf"]
    assert lines[2].split()[1:3] == ["3", "2/1/0/0"]  # DeformableGS, Grid4D and their router
    assert lines[4].startswith("total (deduplicated)") and lines[4].split()[2] == "3"  # the gates reuse them
    assert "deformable (monocular): no reported speed: 4DGaussians'" in text
    assert not (tmp_path / "out").exists() and not (tmp_path / "ws" / "store").exists()


@pytest.mark.parametrize("argv", [[], ["--device", "cpu"]])
def test_the_paper_preset_on_the_cpu_needs_yes(argv, tmp_path, monkeypatch, capsys, gpus):
    gpus(0)
    monkeypatch.setattr(bench.runner, "execute", lambda *a, **k: pytest.fail("ran"))
    out = ["--workspace", str(tmp_path / "ws"), "--out", str(tmp_path / "out")]
    assert main(["--preset", "paper", "--tables", "17", *out, *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: --preset paper on the CPU: about ") and "CPU-hours" in err
    assert err.endswith("pass --yes to run it on the CPU anyway")


def test_the_estimate_reproduces_its_sources():
    """A build at a source's own conditions costs what the source reports, on an H100."""
    dnerf = Work("expert", ("fourdgs",), 23000, 1, 0.64, False)  # 8 min on an RTX 3090
    assert gpu_seconds(dnerf) == pytest.approx(8 * 60 / 2.5, rel=0.05)
    n3v = 1352 * 1014 / 1e6
    ed3dgs = Work("expert", ("ed3dgs",), 80000, 1, n3v, True)  # 4.2 h on an A6000
    assert gpu_seconds(ed3dgs) / 3600 == pytest.approx(4.2 / 2, rel=0.01)
    experts = [
        ed3dgs,
        Work("expert", ("stg",), 10000, 6, n3v, True),
        Work("expert", ("ex4dgs",), 40000, 1, n3v, True),
    ]
    router = Work("moe", ("ed3dgs", "stg", "ex4dgs"), 5000, 1, n3v, True)
    share = gpu_seconds(router) / sum(map(gpu_seconds, experts))
    assert 0.04 < share < 0.06 and ROUTER_FACTOR == 0.6  # the paper: the router adds less than 5%


def test_the_estimate_counts_what_a_build_trains():
    tiny, paper = get_preset("tiny"), get_preset("paper")
    build = _task()
    assert work_of(build, tiny).iterations == 40 and work_of(build, tiny).megapixels == pytest.approx(0.01)
    stg = Task(
        "build",
        "expert",
        {"expert": "stg", "dataset": "n3v"},
        "n3v:coffee_martini",
        {"resolution_scale": 0.5, "frames": [0, 300]},
        "paper",
    )
    work = work_of(stg, paper)
    assert work.passes == 6 and work.megapixels == pytest.approx(1352 * 1014 / 1e6)  # 50-frame segments


# -------------------------------------------------------------------------------- cells and outputs
def _numpy_without_cpu(path: Path) -> list[int]:
    """Lines of ``path`` calling ``.numpy()`` on anything but ``<x>.cpu()``."""
    bad = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "numpy":
            receiver = node.func.value
            on_host = (
                isinstance(receiver, ast.Call)
                and isinstance(receiver.func, ast.Attribute)
                and receiver.func.attr == "cpu"
            )
            if not on_host:
                bad.append(node.lineno)
    return bad


def test_every_numpy_in_the_cells_copies_to_the_host_first(tmp_path):
    found = {p.name: _numpy_without_cpu(p) for p in sorted(CELLS.glob("*.py"))}
    assert {name: lines for name, lines in found.items() if lines} == {}
    probe = tmp_path / "probe.py"
    probe.write_text("a = x.numpy()\nb = x.cpu().numpy()\nc = x.clamp(0, 1).cpu().numpy()\n")
    assert _numpy_without_cpu(probe) == [1]  # the check sees a missing .cpu()


def test_a_run_names_its_device_in_the_report_and_the_run_record(tmp_path):
    from bench.report import write_report

    paths = write_report([], get_preset("tiny"), tmp_path, device="cuda (1 x NVIDIA H100 80GB HBM3)")
    assert "- device: **cuda (1 x NVIDIA H100 80GB HBM3)**" in paths["md"].read_text()
    assert "device: <strong>cuda (1 x NVIDIA H100 80GB HBM3)</strong>" in paths["html"].read_text()
    identity = {"specs": ["tab17"], "keys_digest": "d", "tasks": 5}
    counts = {
        "builds_run": 1,
        "builds_reused": 0,
        "evals_run": 1,
        "evals_reused": 0,
        "failures": [],
        "seconds": 1,
    }
    entry = record_run(tmp_path, "tiny", identity, counts, "local", 1, 60.0, device="cuda (1 x H100)")
    assert "1 jobs on cuda (1 x H100)" in took(entry)
    cpu = record_run(tmp_path, "tiny", identity, counts, "local", 2, 60.0)
    assert "on cpu" not in took(cpu) and cpu["device"] == "cpu"
