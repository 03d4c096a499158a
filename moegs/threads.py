"""Start torch's CPU worker threads before a process computes anything, so that processes compute alike.

Measured with the torch 2.13.0 CPU wheel on a 2-core machine (2 intra-op threads): in about one fresh
process in twenty, the *first* parallel region of the process computes one thread's share of an
elementwise ``sqrt``, ``exp`` or ``log`` differently. ``torch.sqrt`` of 5000 floats gives 2500 values off
by up to 3e-4 (relative), the size of a 12-bit reciprocal-square-root estimate. Division, ``reciprocal``
and ``pow`` were not affected in 50 processes each. Every later call agrees with the usual values, and so
does the first call after any earlier parallel region, even an ``add``: 0 of 160 processes. With one
thread there is no effect (0 of 60).

A run is not affected when its first parallel region is, say, an image conversion, but ``moegs train
--expert static`` computes the 3-NN initial scales (a ``sqrt`` of 5000 values) first. So one process in
twenty started from other scales: a run resumed after ``kill -9`` ended with 4224 Gaussians instead of
4228. The commands and the bench's workers call :func:`start_cpu_workers` first; a script of yours can do
the same. The initial scales are now computed in float64 with numpy's logarithm
(``moegs.data.points.initial_scales``), so they no longer depend on it.
A later ``torch.set_num_threads`` above the count at that call may start new threads (not measured):
call it again after that.

The effect depends on the machine: the numbers above come from the virtual machine where it was found;
on an AMD EPYC virtual machine, 0 of 120 fresh processes computed their first ``sqrt`` differently without
this call (2026-12-02).

This lowers the rate; it does not remove the effect, whose cause inside torch is unknown. After the call
0 of 160 plain processes and 0 of 120 ``moegs train`` processes were hit (about 8 and 6 expected without
it), yet one ``moegs train`` subprocess of a later CI run still started from the other scales (step-1 loss
0.3613119 instead of 0.3613114).
"""

from __future__ import annotations

#: elements per thread of the throwaway operation: above ATen's grain size (32768), so that every thread
#: gets a share
_ELEMENTS_PER_THREAD = 1 << 16


def start_cpu_workers() -> None:
    """Run one parallel ``add`` over all of torch's intra-op threads (about 15 ms on 2 threads here, once
    per process); it leaves no state but the started threads."""
    import torch

    torch.ones(_ELEMENTS_PER_THREAD * torch.get_num_threads()).add_(1.0)
