"""Every expert on the real D-NeRF ``mutant`` scene at the quick preset (100x100, 600 iterations, the
same budget as the ``static`` baseline): a PSNR floor on the 20 test views, and a clear margin over one
static 3DGS trained on all frames (the no-deformation baseline). STG trains mutant's 150 frames as 3
segments of 50 (STG's ``duration``), each with the 600 iterations.

Floors sit 0.5 dB under the lowest value of ``python -m bench.floors`` (seeds 0, 1, 2 x 1 and 2 CPU
threads, rounded down to 0.1 dB; min-max in the comments): a floor at one machine's value is a coin flip
on the next. Measured 2026-12-03 on an AMD EPYC VM with AVX-512 with the library of the committed run
(e0a5830: initial 3-NN scales in float64, STG in segments). 1 and 2 threads gave identical values except
Grid4D (up to 0.14 dB apart) and STG (up to 0.05 dB). An earlier machine check (Intel Xeon with AVX-512,
seed 0, 2026-11-26, older library) gave static 22.58, DeformableGS 27.07, Grid4D 29.19, 4DGaussians 26.20,
MCMC 24.62, E-D3DGS 24.95, STG 27.55, Ex4DGS 25.23.
The runs are shared with the other real-data tests through ``helpers.training`` and cached per code
version."""

from __future__ import annotations

import pytest
from helpers.training import trained_expert

pytestmark = [pytest.mark.slow, pytest.mark.realdata]

MARGIN_OVER_STATIC_DB = 1.0  # seed 0 (what runs here): E-D3DGS 1.88 dB over static, the least; seed 1: 0.49
PSNR_FLOORS = {  # expert: floor (dB); measured min-max over 3 seeds x {1, 2} threads in the comment
    "deformable": 26.4,  # 26.93-27.39
    "grid4d": 28.3,  # 28.87-29.29
    "fourdgs": 25.6,  # 26.14-26.70
    "mcmc": 23.6,  # 24.20-25.53 (seed 0 is the low one)
    "ed3dgs": 22.6,  # 23.14-25.22 (seed 1 is the low one)
    "stg": 27.0,  # 27.50-28.06 as 3 segments of 50 frames
    "ex4dgs": 24.4,  # 24.99-25.54 (seed 2 is the low one)
}


@pytest.mark.parametrize("expert", sorted(PSNR_FLOORS))
def test_expert_beats_static_on_mutant(mutant_root, expert):
    static = trained_expert("static", "dnerf:mutant").metrics["test"]["psnr"]
    result = trained_expert(expert, "dnerf:mutant").metrics
    psnr = result["test"]["psnr"]
    assert result["completed"] and result["test"]["num_views"] == 20
    assert psnr >= PSNR_FLOORS[expert], psnr
    assert psnr > static + MARGIN_OVER_STATIC_DB, (psnr, static)
