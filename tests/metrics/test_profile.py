"""Metric profiles: presets, ids, clamping/quantisation, masks, and the LPIPS-unavailable record."""

from __future__ import annotations

import json

import pytest
import torch

from moegs.metrics import PROFILES, MetricProfile, evaluate_images, get_profile, lpips_available, psnr, ssim
from moegs.metrics import lpips as lpips_fn
from moegs.metrics._images import quantize_u8


def test_presets():
    moegs, clean = PROFILES["moegs"], PROFILES["clean"]
    assert (moegs.ssim_variant, moegs.lpips_net, moegs.lpips_scaling, moegs.clamp, moegs.quantize_u8) == (
        "3dgs",
        "alex",
        "legacy01",
        False,
        False,
    )
    assert (clean.ssim_variant, clean.lpips_scaling, clean.clamp, clean.quantize_u8) == (
        "3dgs",
        "pm1",
        True,
        False,
    )
    assert moegs.id == "moegs/psnr_raw-ssim_3dgs-lpips_alex_legacy01"
    assert clean.id == "clean/psnr_clamp-ssim_3dgs-lpips_alex_pm1"
    assert get_profile("clean") is clean and get_profile(moegs) is moegs
    assert json.loads(json.dumps(moegs.to_dict()))["lpips_scaling"] == "legacy01"


def test_profile_validation():
    with pytest.raises(
        ValueError, match=r"^unknown metric profile 'paper'; valid profiles: 'moegs', 'clean'$"
    ):
        get_profile("paper")
    with pytest.raises(ValueError, match=r"^MetricProfile.ssim_variant 'x' not in"):
        MetricProfile("custom", ssim_variant="x")
    with pytest.raises(ValueError, match=r"^MetricProfile.lpips_scaling 'raw' not in"):
        MetricProfile("custom", lpips_scaling="raw")


def test_moegs_is_unclamped_and_clean_is_clamped(frame, gen):
    pred = frame + 0.08 * torch.randn(frame.shape, generator=gen)  # overshoots [0, 1] on the white background
    raw, clean = evaluate_images(pred, frame, "moegs"), evaluate_images(pred, frame, "clean")
    assert raw["psnr"] == pytest.approx(psnr(pred, frame).item(), abs=1e-6)
    assert clean["psnr"] == pytest.approx(psnr(pred.clamp(0, 1), frame).item(), abs=1e-6)
    assert clean["psnr"] > raw["psnr"] + 0.5  # clamping removes the overshoot error
    assert raw["ssim"] == pytest.approx(ssim(pred, frame).item(), abs=1e-6)
    assert raw["profile"]["id"] == PROFILES["moegs"].id and clean["profile"]["name"] == "clean"
    if lpips_available():
        assert raw["lpips"] == pytest.approx(lpips_fn(pred, frame, scaling="legacy01").item(), abs=1e-6)
        assert clean["lpips"] == pytest.approx(lpips_fn(pred.clamp(0, 1), frame).item(), abs=1e-6)
        assert raw["lpips_unavailable"] is None
    json.dumps(raw)


def test_quantize_u8(frame, gen):
    pred = frame + 0.03 * torch.randn(frame.shape, generator=gen)
    profile = MetricProfile("png", quantize_u8=True)
    assert profile.id == "png/psnr_u8-ssim_3dgs-lpips_alex_pm1"
    out = evaluate_images(pred, frame, profile)
    q = quantize_u8(pred)
    assert torch.equal(q * 255, torch.round(q * 255)) and q.min() >= 0 and q.max() <= 1
    assert out["psnr"] == pytest.approx(psnr(q, quantize_u8(frame)).item(), abs=1e-6)
    # round-half-up like torchvision save_image: 0.5/255 goes up, just below goes down
    edge = torch.tensor([0.5 / 255 + 1e-6, 0.5 / 255 - 1e-6])
    assert (quantize_u8(edge) * 255).tolist() == [1.0, 0.0]


def test_a_batch_gives_each_image_its_own_values(frame, degraded):
    preds = torch.stack(list(degraded.values()))
    out = evaluate_images(preds, frame.expand_as(preds), "clean")
    singles = [evaluate_images(p, frame, "clean") for p in preds]
    for key in ("psnr", "ssim", "lpips"):
        if out[key] is None:  # LPIPS without its weights: None for the batch and for each image
            assert all(s[key] is None for s in singles)
            continue
        assert isinstance(out[key], list) and len(out[key]) == len(preds)
        assert out[key] == pytest.approx([s[key] for s in singles], abs=1e-5), key


def test_mask_and_unavailable_lpips(frame, degraded, monkeypatch, tmp_path):
    mask = torch.zeros(128, 128, dtype=torch.bool)
    mask[20:90, 30:100] = True
    out = evaluate_images(degraded["blur"], frame, "moegs", mask=mask)
    assert out["masked"]
    if lpips_available():  # staged under MOEGS_DATA: a missing value is a regression, not a missing file
        assert out["lpips"] is not None and out["lpips_unavailable"] is None
        region = lpips_fn(degraded["blur"], frame, "alex", "legacy01", mask=mask.float()).item()
        assert out["lpips"] == pytest.approx(region, rel=1e-6)  # the region's LPIPS, not the image's
        assert out["lpips"] != pytest.approx(evaluate_images(degraded["blur"], frame, "moegs")["lpips"])
    else:
        assert out["lpips"] is None and out["lpips_unavailable"]
    assert out["psnr"] == pytest.approx(psnr(degraded["blur"], frame, mask).item(), abs=1e-6)
    with_weights = evaluate_images(degraded["blur"], frame, "clean")
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    out = evaluate_images(degraded["blur"], frame, "clean")
    assert out["lpips"] is None and str(tmp_path) in out["lpips_unavailable"]
    assert out["psnr"] == with_weights["psnr"] and out["ssim"] == with_weights["ssim"]  # LPIPS alone is gone
