"""The photometric loss of the 3DGS lineage: ``(1 - lambda) L1 + lambda (1 - SSIM)``."""

from __future__ import annotations

import pytest
import torch

from moegs.metrics import ssim
from moegs.train.losses import dssim, l1, photometric


@pytest.fixture
def pair():
    g = torch.Generator().manual_seed(0)
    return torch.rand(16, 20, 3, generator=g), torch.rand(16, 20, 3, generator=g)


def test_l1_and_dssim_by_hand(pair):
    pred, target = pair
    assert float(l1(pred, target)) == pytest.approx(float((pred - target).abs().mean()))
    assert float(dssim(pred, target)) == pytest.approx(1.0 - float(ssim(pred, target, variant="3dgs")))
    assert float(dssim(pred, pred)) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("lambda_dssim", [0.0, 0.2, 1.0])
def test_photometric_mixes_l1_and_dssim(pair, lambda_dssim):
    pred, target = pair
    expected = (1.0 - lambda_dssim) * l1(pred, target) + lambda_dssim * dssim(pred, target)
    torch.testing.assert_close(photometric(pred, target, lambda_dssim), expected)


def test_bad_arguments_are_named(pair):
    pred, target = pair
    with pytest.raises(ValueError, match=r"lambda_dssim must be in \[0, 1\], got 1.5"):
        photometric(pred, target, 1.5)
    with pytest.raises(ValueError, match=r"l1: pred \[16, 20, 3\] and target \[16, 19, 3\] differ"):
        l1(pred, target[:, :19])
