"""The runner's scheduler: a task starts as soon as its own dependencies are built, never waiting for
unrelated work; failures block exactly what is downstream of them; capacity and priority hold. ``execute``
around it: finished work is reused, and what failed or was blocked is recorded."""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import pytest
from helpers.cells import write_ok_result

from bench.executors import Outcome
from bench.results import read_result
from bench.runner import execute, heights, schedule
from bench.store import Workspace


def _task(key: str, action: str = "build") -> SimpleNamespace:
    return SimpleNamespace(
        key=key,
        slug=f"{action}-{key}",
        action=action,
        kind="fake",
        preset="quick",
        to_dict=lambda: {"key": key},
        identity=lambda: {"key": key},
    )


class FakeExecutor:
    """Runs ``bodies[key]()`` (True: ok) on threads; records start order and peak concurrency."""

    def __init__(self, capacity: int, bodies: dict | None = None) -> None:
        self.capacity = capacity
        self.bodies = bodies or {}
        self.started: list[str] = []
        self.running = self.peak = 0
        self.closed = False
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=8)

    def _run(self, task) -> Outcome:
        ok = self.bodies.get(task.key, lambda: True)()
        with self._lock:
            self.running -= 1
        return Outcome(task, ok, Path(f"{task.key}.log"), 0.0, "" if ok else "boom")

    def submit(self, task, workspace) -> Future:
        with self._lock:
            self.started.append(task.key)
            self.running += 1
            self.peak = max(self.peak, self.running)
        return self._pool.submit(self._run, task)

    def interrupt(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def _run(tasks, graph, executor):
    outcomes, blocked = [], {}
    tasks = {t.key: t for t in tasks}
    schedule(tasks, graph, executor, None, outcomes.append, lambda t, why: blocked.__setitem__(t.key, why))
    return outcomes, blocked


def test_a_dependent_starts_while_an_unrelated_long_task_runs():
    """router(b) needs expert b only: it starts while expert a (the longest) still trains."""
    router_started = threading.Event()
    a_finished_first = []

    def long_expert():
        a_finished_first.append(not router_started.wait(timeout=10))
        return True

    ex = FakeExecutor(2, {"a": long_expert, "router": lambda: router_started.set() or True})
    outcomes, blocked = _run(
        [_task("a"), _task("b"), _task("router")], {"a": [], "b": [], "router": ["b"]}, ex
    )
    assert a_finished_first == [False]  # level-by-level scheduling would wait 10 s, then fail this
    assert sorted(o.task.key for o in outcomes) == ["a", "b", "router"] and not blocked
    assert ex.closed


def test_a_failure_blocks_everything_downstream_and_nothing_else():
    ex = FakeExecutor(2, {"b": lambda: False})
    tasks = [_task("a"), _task("b"), _task("router"), _task("cell", "eval"), _task("other", "eval")]
    graph = {"a": [], "b": [], "router": ["b"], "cell": ["router", "b"], "other": ["a"]}
    outcomes, blocked = _run(tasks, graph, ex)
    assert sorted(o.task.key for o in outcomes) == ["a", "b", "other"]
    assert set(blocked) == {"router", "cell"}
    assert blocked["router"] == "dependency build-b failed (log b.log)"
    assert "build-" in blocked["cell"] and "failed" in blocked["cell"]


def test_a_failure_blocks_a_chain_listed_before_its_link():
    """The cell depends on the router only; it comes first in plan order, so the pass that blocks the router
    has already looked at it: blocking must go on until nothing more is blocked."""
    ex = FakeExecutor(1, {"b": lambda: False})
    tasks = [_task("cell", "eval"), _task("b"), _task("router")]
    outcomes, blocked = _run(tasks, {"cell": ["router"], "b": [], "router": ["b"]}, ex)
    assert [o.task.key for o in outcomes] == ["b"]
    assert blocked == {
        "router": "dependency build-b failed (log b.log)",
        "cell": "dependency build-router failed (dependency build-b failed (log b.log))",
    }


def test_capacity_and_longest_chain_first():
    """One slot: the build with a chain of dependents goes before a ready cell listed first."""
    ex = FakeExecutor(1)
    tasks = [_task("cell", "eval"), _task("expert"), _task("router"), _task("moe_cell", "eval")]
    graph = {"cell": [], "expert": [], "router": ["expert"], "moe_cell": ["router"]}
    _run(tasks, graph, ex)
    assert ex.started == ["expert", "router", "cell", "moe_cell"]  # ties: plan order
    assert ex.peak == 1
    # three slots: the first three tasks can only finish together (a barrier), so they must run at once
    barrier = threading.Barrier(3)
    together = {str(i): lambda: barrier.wait(timeout=30) >= 0 for i in range(3)}
    wide = FakeExecutor(3, together)
    outcomes, _ = _run([_task(str(i), "eval") for i in range(7)], {str(i): [] for i in range(7)}, wide)
    assert wide.peak == 3 and len(wide.started) == 7 and all(o.ok for o in outcomes)


def test_heights():
    assert heights({"e": [], "r": ["e"], "c": ["r", "e"], "x": []}) == {"e": 2, "r": 1, "c": 0, "x": 0}


def test_ctrl_c_interrupts_the_executor():
    class Interrupting(FakeExecutor):
        interrupted = False

        def submit(self, task, workspace):
            raise KeyboardInterrupt

        def interrupt(self):
            self.interrupted = True

    ex = Interrupting(1)
    with pytest.raises(KeyboardInterrupt):
        _run([_task("a")], {"a": []}, ex)
    assert ex.interrupted and ex.closed


def test_execute_reuses_finished_work_and_records_what_it_could_not_do(tmp_path, monkeypatch):
    """Expert e1 is built and cell c2 evaluated already; e2 fails, so its cell c1 gets a ``failed`` result
    naming it; c4's result file is broken, so it is recomputed and the file named."""
    monkeypatch.setattr("bench.runner._deps", lambda task: [])
    ws = Workspace(tmp_path)
    e1, e2 = _task("e1"), _task("e2")
    c1, c2, c3, c4 = (_task(f"c{i}", "eval") for i in range(1, 5))

    def build(folder: Path) -> dict:
        (folder / "model.pt").write_text("weights")
        return {}

    ws.ensure(e1, build)
    write_ok_result(ws, c2)
    ws.result_path(c4).write_text("{")
    needs = {"c1": [e2], "c2": [e1], "c3": [e1], "c4": [e1]}
    plan = SimpleNamespace(
        build_levels=lambda: [[e1, e2]], eval_tasks=lambda: [c1, c2, c3, c4], closure=lambda t: needs[t.key]
    )
    summary = execute(plan, ws, FakeExecutor(1, {"e2": lambda: False}), progress=False)
    counts = (summary.builds_reused, summary.builds_run, summary.evals_reused, summary.evals_run)
    assert counts == (1, 1, 1, 2)
    assert [o.task.key for o in summary.failures] == ["e2"] and not summary.ok
    assert summary.blocked == {"c1": "dependency build-e2 failed (log e2.log)"}
    failed = read_result(ws.result_path(c1))
    assert failed["status"] == "failed" and failed["error"] == summary.blocked["c1"]
    assert len(summary.invalid_results) == 1 and str(ws.result_path(c4)) in summary.invalid_results[0]
    assert not ws.result_path(c3).exists()  # the fake executor evaluates nothing: no result is invented
