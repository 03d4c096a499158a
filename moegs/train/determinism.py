"""Repeatable training: PyTorch's deterministic kernels for the duration of a run.

Seeds alone do not make CPU runs repeat: a few backward kernels (the gradient of ``x[idx]`` with
repeated indices, i.e. an accumulating ``index_put_``) add their terms in the order the threads finish.
E-D3DGS's neighbour-smoothness loss made two identical 120-step runs on mutant differ in the fifth
digit of the loss, and 0.3 dB apart after 600 steps. ``train`` and ``train_router`` run under
``deterministic_kernels``; the caller's setting is restored afterwards.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import torch

F = TypeVar("F", bound=Callable)


@contextmanager
def deterministic_kernels() -> Iterator[None]:
    """``torch.use_deterministic_algorithms(True, warn_only=True)`` inside the block (an op without a
    deterministic kernel warns instead of failing), the previous setting after it."""
    previous = torch.are_deterministic_algorithms_enabled()
    previous_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous, warn_only=previous_warn_only)


def deterministic(fn: F) -> F:
    """Decorator: run ``fn`` under ``deterministic_kernels``."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with deterministic_kernels():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
