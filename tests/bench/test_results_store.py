"""Task keys, result files (atomic, validated, errors name the file), the artefact store, claim checks."""

from __future__ import annotations

import json
import threading
import time

import pytest

from bench.claims import FAILED, HELD, NA, better, monotone, order
from bench.keys import code_version, digest, plugin_sources
from bench.results import (
    SCHEMA,
    ResultError,
    atomic_path,
    load_valid,
    read_result,
    write_json_atomic,
    write_result,
    write_text_atomic,
)
from bench.store import Workspace
from bench.tasks import Task


def _task(**kw) -> Task:
    base = {
        "action": "eval",
        "kind": "expert",
        "params": {"expert": "static"},
        "scene": "dnerf:mutant",
        "scene_kwargs": {"resolution_scale": 0.0625},
        "preset": "tiny",
        "seed": 0,
    }
    return Task(**{**base, **kw})


def test_task_key_is_content_addressed():
    a, b = _task(), _task()
    assert a == b and a.key == b.key and len({a, b}) == 1
    assert _task(seed=1).key != a.key
    assert _task(params={"expert": "mcmc"}).key != a.key
    assert _task(preset="quick").key != a.key
    assert a.identity()["code_version"] == a.code_version  # the library code it runs (test_codedeps)
    assert Task.from_dict(a.to_dict()) == a
    assert digest({"x": (1, 2)}) == digest({"x": [1, 2]})


@pytest.fixture
def uncached_code_version():
    """``code_version`` computed afresh inside the test, and again for the tests after it."""
    code_version.cache_clear()
    yield
    code_version.cache_clear()


def test_code_version_pin(monkeypatch, uncached_code_version):
    monkeypatch.setenv("MOEGS_BENCH_CODE_VERSION", "pinned")
    assert _task().identity()["code_version"] == "pinned"


def test_code_version_hashes_python_and_the_c_kernel_but_not_docstrings(
    tmp_path, monkeypatch, uncached_code_version
):
    (tmp_path / "moegs" / "kernels").mkdir(parents=True)
    module, kernel = tmp_path / "moegs" / "a.py", tmp_path / "moegs" / "kernels" / "raster.c"
    module.write_text('"""Doc."""\nX = 1\n')
    kernel.write_text("int f(void) { return 1; }\n")
    monkeypatch.setattr("bench.keys.REPO", tmp_path)
    monkeypatch.setattr("bench.keys.plugin_sources", lambda: [])

    def version() -> str:
        code_version.cache_clear()
        return code_version()

    first = version()
    module.write_text('"""Other words."""\nX = 1\n')
    assert version() == first
    kernel.write_text("int f(void) { return 2; }\n")
    assert version() != first


def test_the_version_holds_each_plugin_experts_module_source(tmp_path, monkeypatch):
    """A plugin expert lives outside the repository: its module's source is part of the version."""
    import moegs.experts
    from moegs.experts import ExpertSpec

    module = tmp_path / "my_plugin_expert.py"
    module.write_text("class MyExpert: ...\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    builtin = moegs.experts.list_experts()
    plugin = ExpertSpec("mine", "my_plugin_expert:MyExpert", "a plugin", plugin="my-dist")
    monkeypatch.setattr(moegs.experts, "list_experts", lambda: [*builtin, plugin])
    assert plugin_sources() == [("mine", b"class MyExpert: ...\n")]
    module.write_text("class MyExpert: pass\n")
    assert plugin_sources() == [("mine", b"class MyExpert: pass\n")]


def _result(task: Task, **kw) -> dict:
    return {
        "schema": SCHEMA,
        "status": "ok",
        "key": task.key,
        "task": task.to_dict(),
        "metrics": {"psnr": 30.0},
        "versions": {},
        "timings": {},
        **kw,
    }


def test_result_roundtrip_and_validation(tmp_path):
    ws = Workspace(tmp_path)
    task = _task()
    path = ws.result_path(task)
    assert load_valid(path, task) is None  # not computed yet
    write_result(path, _result(task))
    assert load_valid(path, task)["metrics"]["psnr"] == 30.0
    assert not list(path.parent.glob(".*tmp*")), "atomic write leaves no temporary file"
    write_result(path, _result(task, status="failed"))
    assert load_valid(path, task) is None  # failed results are recomputed


@pytest.mark.parametrize(
    "content,message",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        ('{"schema": "x"}', "missing field"),
    ],
)
def test_bad_result_file_names_the_file(tmp_path, content, message):
    task = _task()
    path = Workspace(tmp_path).result_path(task)
    path.parent.mkdir(parents=True)
    path.write_text(content)
    with pytest.raises(ResultError, match=message) as err:
        load_valid(path, task)
    assert str(path) in str(err.value)


def test_an_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "out" / "REPORT.md"
    write_text_atomic(path, "old\n")
    with pytest.raises(KeyboardInterrupt), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert path.read_text() == "old\n" and sorted(p.name for p in path.parent.iterdir()) == ["REPORT.md"]
    write_text_atomic(path, "new\n")
    assert path.read_text() == "new\n" and len(list(path.parent.iterdir())) == 1


def test_result_key_must_match_file(tmp_path):
    task = _task()
    path = tmp_path / "other.json"
    write_result(path, _result(task))
    with pytest.raises(ResultError, match="does not match the file name"):
        read_result(path)


def _builder(meta: dict):
    """A build function writing ``checkpoint.bin`` and returning ``meta``, and the list of its calls."""
    calls = []

    def build(out):
        calls.append(1)
        (out / "checkpoint.bin").write_bytes(b"weights")
        return dict(meta)

    return build, calls


def test_store_builds_once_under_concurrency(tmp_path):
    ws = Workspace(tmp_path)
    task = _task(action="build")
    build, calls = _builder({"train_seconds": 1.0})
    arrived = threading.Barrier(4)

    def slow_build(out):  # long enough that every other thread asks while it runs
        time.sleep(0.3)
        return build(out)

    def ensure() -> None:  # the four threads call ensure at the same moment
        arrived.wait(timeout=30)
        ws.ensure(task, slow_build)

    threads = [threading.Thread(target=ensure) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and ws.is_built(task)
    meta = ws.artifact_meta(task)
    assert meta["key"] == task.key and "checkpoint.bin" in meta["files"] and meta["train_seconds"] == 1.0


def test_store_failed_build_leaves_nothing_finished(tmp_path):
    ws = Workspace(tmp_path)
    task = _task(action="build")

    def boom(out):
        raise RuntimeError("training diverged")

    with pytest.raises(RuntimeError):
        ws.ensure(task, boom)
    assert not ws.is_built(task)
    with pytest.raises(Exception, match="not built"):
        ws.artifact_meta(task)


def test_edited_result_is_refused(tmp_path):
    """A hand-edited number (or a damaged file) no longer matches the content hash: the cell recomputes."""
    task = _task()
    path = Workspace(tmp_path).result_path(task)
    write_result(path, _result(task))
    data = json.loads(path.read_text())
    data["metrics"]["psnr"] = 99.0
    path.write_text(json.dumps(data))
    with pytest.raises(ResultError, match="does not match its content_sha256") as err:
        load_valid(path, task)
    assert str(path) in str(err.value)
    del data["content_sha256"]
    write_json_atomic(path, data)
    with pytest.raises(ResultError, match=r"missing field\(s\) \['content_sha256'\]"):
        load_valid(path, task)


def _built(tmp_path):
    ws = Workspace(tmp_path)
    task = _task(action="build")
    build, calls = _builder({})
    ws.ensure(task, build)
    return ws, task, build, calls


@pytest.mark.parametrize("damage", ["flip", "truncate", "delete"])
def test_damaged_artefact_is_detected_and_rebuilt(tmp_path, damage):
    ws, task, build, calls = _built(tmp_path)
    path = ws.artifact_dir(task) / "checkpoint.bin"
    if damage == "flip":
        path.write_bytes(b"weightS")
    elif damage == "truncate":
        path.write_bytes(b"wei")
    else:
        path.unlink()
    fresh = Workspace(tmp_path)  # a new process: nothing verified yet
    message = "missing" if damage == "delete" else "differs from"
    with pytest.raises(Exception, match=message) as err:
        fresh.verify(task)
    assert str(path) in str(err.value)
    assert not fresh.is_built(task)
    warnings = []
    fresh.ensure(task, build, warn=warnings.append)
    assert len(calls) == 2 and fresh.is_built(task) and path.read_bytes() == b"weights"
    assert "damaged artefact, rebuilding" in warnings[0]
    assert len(list(ws.artifact_dir(task).parent.glob(f"{task.key}.corrupt-*"))) == 1  # kept for a look


def test_intact_artefact_is_not_rebuilt(tmp_path):
    ws, task, build, calls = _built(tmp_path)
    fresh = Workspace(tmp_path)
    assert fresh.is_built(task)
    fresh.ensure(task, build)
    assert len(calls) == 1


def test_an_artefact_without_file_hashes_is_not_built(tmp_path):
    ws, task, _, _ = _built(tmp_path)
    meta = ws.artifact_dir(task) / "artifact.json"
    meta.write_text(json.dumps({k: v for k, v in json.loads(meta.read_text()).items() if k != "files"}))
    fresh = Workspace(tmp_path)
    with pytest.raises(Exception, match="records no file hashes") as err:
        fresh.verify(task)
    assert str(ws.artifact_dir(task)) in str(err.value) and not fresh.is_built(task)


def test_a_successful_build_clears_the_failure_a_worker_left(tmp_path):
    ws, task = Workspace(tmp_path), _task(action="build")
    ws.failure_path(task).parent.mkdir(parents=True)
    ws.failure_path(task).write_text('{"error": "out of memory"}')
    build, _ = _builder({})
    ws.ensure(task, build)
    assert ws.is_built(task) and not ws.failure_path(task).exists()


def test_non_finite_metrics_fail_the_cell():
    from bench.worker import check_finite_metrics

    check_finite_metrics({"psnr": 30.0, "fps": None, "count": 3})
    for bad in (float("nan"), float("inf"), float("-inf")):
        with pytest.raises(ValueError, match="non-finite metric"):
            check_finite_metrics({"psnr": bad})


class _View:
    def __init__(self, data):
        self.data = data

    def get(self, row, column, metric):
        return self.data.get((row, column, metric))

    def columns(self, selector):
        return ["A", "B"] if selector == "@scenes" else (["avg"] if selector == "@mean" else list(selector))

    def metrics_of(self, column):
        return list(dict.fromkeys(m for _, c, m in self.data if c == column))


def test_claim_checks():
    v = _View(
        {
            ("moe", "A", "PSNR"): 30.0,
            ("e1", "A", "PSNR"): 29.0,
            ("moe", "B", "PSNR"): 31.0,
            ("e1", "B", "PSNR"): 31.5,
            ("moe", "A", "LPIPS"): 0.1,
            ("e1", "A", "LPIPS"): 0.2,
        }
    )
    assert better(v, "moe", "e1", columns=["A"]).status == HELD
    assert better(v, "moe", "e1", columns="@scenes").status == FAILED
    assert better(v, "moe", "e1", metric="LPIPS", columns=["A"]).status == HELD  # lower is better
    assert better(v, "moe", "missing", columns=["A"]).status == NA
    assert order(v, ["e1", "moe"], columns=["B"]).status == HELD
    assert monotone(v, ["moe"], ["B", "A"]).status == HELD
    assert monotone(v, ["moe"], ["A", "B"]).status == FAILED


def test_workspace_layout(tmp_path, monkeypatch):
    monkeypatch.delenv("MOEGS_BENCH_DIR", raising=False)
    monkeypatch.chdir(tmp_path)
    assert Workspace().root == tmp_path / "runs" / "bench"  # the working directory, never the install tree
    monkeypatch.setenv("MOEGS_BENCH_DIR", str(tmp_path / "elsewhere"))
    assert Workspace().root == tmp_path / "elsewhere"
    ws = Workspace(tmp_path)
    task = _task()
    assert ws.result_path(task).parent.name == "expert"
    assert ws.result_path(task).name == f"{task.key}.json"
    assert str(ws.log_path(task)).endswith(f"eval/expert/{task.key}.log")
    json.dumps(task.identity())  # JSON-serialisable
