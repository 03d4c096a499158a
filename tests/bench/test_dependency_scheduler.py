"""The runner's scheduler: a task starts as soon as its own dependencies are built, never waiting for
unrelated work; failures block exactly what is downstream of them; capacity and priority hold."""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.executors import Outcome
from bench.runner import heights, schedule


def _task(key: str, action: str = "build") -> SimpleNamespace:
    return SimpleNamespace(key=key, slug=f"{action}-{key}", action=action)


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
