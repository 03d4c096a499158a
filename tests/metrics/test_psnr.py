"""PSNR: closed-form values, the MoE-GS m_psnr mask normalisation, skimage agreement, exact errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from moegs.metrics import psnr


def test_closed_form_and_shapes(gen):
    x = torch.rand(2, 8, 9, 3, generator=gen)
    out = psnr(x + 0.1, x)
    assert out.shape == (2,)
    torch.testing.assert_close(out, torch.full((2,), 20.0), atol=1e-4, rtol=0)
    single = psnr(x[0] + 0.01, x[0])
    assert single.ndim == 0 and abs(single.item() - 40.0) < 1e-3
    assert math.isinf(psnr(x[0], x[0]).item())


def test_batch_is_per_image_not_pooled(gen):
    x = torch.rand(2, 8, 8, 3, generator=gen)
    y = x.clone()
    y[0] += 0.1
    y[1] += 0.01
    torch.testing.assert_close(psnr(y, x), torch.stack([psnr(y[0], x[0]), psnr(y[1], x[1])]))


def test_matches_skimage_on_real_frame(frame, degraded):
    from skimage.metrics import peak_signal_noise_ratio

    for pred in degraded.values():
        ref = peak_signal_noise_ratio(frame.double().numpy(), pred.double().numpy(), data_range=1.0)
        assert abs(psnr(pred.double(), frame.double()).item() - ref) < 1e-9


def test_mask_normalises_by_mask_count(gen):
    x = torch.rand(10, 10, 3, generator=gen)
    y = x.clone()
    y[:5] += 0.1  # error only in the top half
    top = torch.zeros(10, 10, dtype=torch.bool)
    top[:5] = True
    assert abs(psnr(y, x, top).item() - 20.0) < 1e-4  # MSE over the ROI only, counted once per channel
    assert math.isinf(psnr(y, x, ~top).item())
    ones = torch.ones(10, 10)
    torch.testing.assert_close(psnr(y, x, ones), psnr(y, x))
    for form in (top[..., None], top[..., None].expand(10, 10, 3), top.float()):
        torch.testing.assert_close(psnr(y, x, form), psnr(y, x, top))
    assert math.isnan(psnr(y, x, torch.zeros(10, 10)).item())


def test_mask_matches_reference_formula(frame, degraded):
    # MoE-GS image_utils.m_psnr: sum(mask_b * d^2) / sum(mask_b) with the mask repeated over channels
    pred = degraded["noise"]
    mask = torch.zeros(128, 128)
    mask[30:90, 20:110] = 1.0
    d2 = (pred - frame).square().numpy()
    m = np.repeat(mask.numpy()[..., None], 3, axis=-1)
    ref = 20 * np.log10(1.0 / np.sqrt((d2 * m).sum() / m.sum()))
    assert abs(psnr(pred, frame, mask).item() - ref) < 1e-4
    batch = psnr(torch.stack([pred, pred]), torch.stack([frame, frame]), torch.stack([mask, mask]))
    torch.testing.assert_close(batch, torch.full((2,), float(ref)), atol=1e-4, rtol=0)


def test_exceptions():
    x = torch.rand(8, 8, 3)
    with pytest.raises(
        ValueError, match=r"^psnr: `pred` must have shape \[H, W, C\] or \[B, H, W, C\], got \[8, 8\]$"
    ):
        psnr(x[..., 0], x[..., 0])
    with pytest.raises(
        TypeError, match=r"^psnr: `target` must be a floating-point tensor in \[0, 1\], got torch.uint8$"
    ):
        psnr(x, (x * 255).to(torch.uint8))
    with pytest.raises(
        ValueError,
        match=r"^psnr: `pred` and `target` must have the same shape, got \[8, 8, 3\] and \[8, 7, 3\]$",
    ):
        psnr(x, x[:, :7])
    with pytest.raises(
        ValueError,
        match=r"^psnr: `mask` must have shape \[H, W\], \[H, W, 1\] or \[H, W, C\] "
        r"matching `pred` \[8, 8, 3\], got \[8, 7\]$",
    ):
        psnr(x, x, torch.ones(8, 7))
    with pytest.raises(TypeError, match=r"^psnr: `pred` must be a torch.Tensor, got ndarray$"):
        psnr(x.numpy(), x)
