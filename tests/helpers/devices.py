"""Device checks that run on a CPU-only machine.

* :func:`poisoned_default_device`: inside it every tensor created without an explicit device lands on the
  ``meta`` device, so library code that forgets ``device=`` fails at the first operation mixing it with a
  real tensor (``Tensor on device meta is not on the expected device cpu``), with the traceback naming the
  line. On CUDA the same tensor would be on the CPU and raise there.
* :class:`HostReads`: counts the calls of library code that read a tensor's value on the host (``.item()``,
  ``bool(t)``, ``int(t)``, ``.tolist()``, a boolean mask index, ``nonzero`` ...), by file and line. On CUDA
  each of these waits for the GPU (a host synchronisation); on the CPU they cost nothing, so the budget
  tests count them here.
"""

from __future__ import annotations

import contextlib
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import torch
from torch import Tensor
from torch.overrides import TorchFunctionMode

MOEGS = str(Path(__file__).resolve().parents[2] / "moegs")

#: operations that return a host value computed from a tensor's data (a CUDA synchronisation)
_READS = {
    Tensor.item,
    Tensor.tolist,
    Tensor.__bool__,
    Tensor.__int__,
    Tensor.__float__,
    Tensor.__index__,
    Tensor.numpy,
    Tensor.nonzero,
    torch.nonzero,
    torch.unique,
    Tensor.unique,
    torch.masked_select,
    Tensor.masked_select,
    Tensor.cpu,  # a copy to the host: a sync for a CUDA tensor
}
#: operations whose output size depends on the data (CUDA reads a count back)
_SIZED_BY_DATA = {torch.repeat_interleave, Tensor.repeat_interleave}


def _has_bool_index(index) -> bool:
    items = index if isinstance(index, tuple) else (index,)
    return any(isinstance(i, Tensor) and i.dtype == torch.bool for i in items)


def _is_read(func, args, kwargs) -> bool:
    if func in _READS:
        return True
    if func in _SIZED_BY_DATA:
        return "output_size" not in kwargs
    if func is Tensor.__getitem__ and len(args) > 1:
        return _has_bool_index(args[1])
    if func is torch.where and len(args) == 1 and not kwargs:
        return True
    return func is Tensor.to and any(
        (isinstance(a, str | torch.device) and torch.device(a).type == "cpu") for a in args[1:]
    )


class HostReads(TorchFunctionMode):
    """Counts host reads made directly by ``moegs`` code (``counts``: ``"moegs/x.py:12" -> n``); reads made
    inside torch (an optimiser's step counter) are torch's and not counted."""

    def __init__(self) -> None:
        super().__init__()
        self.counts: Counter[str] = Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if _is_read(func, args, kwargs):
            caller = sys._getframe(1)
            while caller is not None and caller.f_code.co_filename == __file__:
                caller = caller.f_back
            if caller is not None and caller.f_code.co_filename.startswith(MOEGS):
                where = Path(caller.f_code.co_filename).relative_to(Path(MOEGS).parent)
                self.counts[f"{where}:{caller.f_lineno}"] += 1
        return func(*args, **kwargs)

    @property
    def total(self) -> int:
        return sum(self.counts.values())


@contextlib.contextmanager
def poisoned_default_device() -> Iterator[None]:
    """Tensors created without a device inside the block are ``meta`` tensors (see module docstring)."""
    with torch.device("meta"):
        yield
