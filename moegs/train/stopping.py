"""Stopping a training loop cleanly: SIGINT / SIGTERM finish the current step, the loop writes its
checkpoint and raises :class:`~moegs.errors.TrainingInterrupted` (used by the expert and router loops)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

from moegs.errors import TrainingInterrupted


@contextlib.contextmanager
def stop_requests(enabled: bool) -> Iterator[dict]:
    """While active, SIGINT and SIGTERM only set ``flag["signal"]`` for the loop to act on (signal handlers
    exist only in the main thread; elsewhere, or when not ``enabled``, this does nothing)."""
    flag: dict = {"signal": None}
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def request(signum, _frame) -> None:
        flag["signal"] = signum

    previous = {s: signal.signal(s, request) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def raise_if_stopped(flag: dict, step: int, iterations: int, checkpoint: Path | None) -> None:
    """``TrainingInterrupted`` naming the signal, the step and the checkpoint when ``flag`` holds a signal
    that arrived before the last step."""
    if flag["signal"] is None or step >= iterations:
        return
    name = signal.Signals(flag["signal"]).name
    raise TrainingInterrupted(
        f"{name} after step {step} of {iterations}; checkpoint saved to {checkpoint}: "
        "run the same command again to resume"
    )
