"""LPIPS-Alex: the published reference pair, zero on identical images, gradients, the scaling trap,
the weight-file layout, and the unavailable-weights path."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from moegs.metrics import LPIPS, LPIPSUnavailable, lpips, lpips_available
from moegs.metrics.lpips import _alex_state, _to_oihw, lpips_weights_dir

needs_weights = pytest.mark.skipif(
    not lpips_available(),
    reason=f"LPIPS-alex weights absent (looked in {lpips_weights_dir()}); set MOEGS_DATA",
)
REFERENCE = 0.44629833


def _reference_image(name: str) -> torch.Tensor:
    """The lpips_torch2tf demo input: PNG read as gray 0..255, repeated to RGB, ``[64, 64, 3]``.

    Its notebook builds ``LPIPS(pre_norm=True)``, which min-max scales each image to [-1, 1]; here that
    is min-max to [0, 1] followed by the "pm1" rescaling (identical). Dividing by 255 instead gives
    0.424, outside the tolerance, so the min-max step is part of the reference.
    """
    from PIL import Image

    path = lpips_weights_dir().parent.parent / "reference" / f"{name}.png"
    gray = np.asarray(Image.open(path).convert("L"), dtype=np.float64)
    gray = (gray - gray.min()) / (gray.max() - gray.min())
    return torch.from_numpy(gray).float()[..., None].repeat(1, 1, 3)


@needs_weights
def test_reference_pair():
    value = lpips(_reference_image("image_noise"), _reference_image("image")).item()
    assert abs(value - REFERENCE) < 2e-3, value


def test_kernel_layout_matches_converter(gen):
    """lpips_torch2tf stores ``swapaxes(swapaxes(w_oihw, 0, -1), 1, -2)``; ``_to_oihw`` must invert it."""
    w = torch.randn(6, 3, 5, 7, generator=gen)
    stored = w.numpy().swapaxes(0, -1).swapaxes(1, -2)
    assert stored.shape == (7, 5, 3, 6)
    torch.testing.assert_close(_to_oihw(torch.from_numpy(stored.copy())), w, atol=0, rtol=0)


@needs_weights
def test_identical_is_zero_and_symmetric(frame, degraded):
    assert lpips(frame, frame).item() == 0.0
    pred = degraded["noise"]
    assert abs(lpips(pred, frame).item() - lpips(frame, pred).item()) < 1e-6


@needs_weights
def test_masked_lpips_averages_the_spatial_map_over_the_region(frame, gen):
    """Region LPIPS: where the images differ it is larger than where they agree, a mask's scale does
    not matter, a full mask gives the spatial map's mean (close to the plain value), identical images 0."""
    left = torch.zeros(frame.shape[:2])
    left[:, : frame.shape[1] // 2] = 1.0
    pred = frame.clone()
    pred[:, : frame.shape[1] // 2] = (
        pred[:, : frame.shape[1] // 2]
        + 0.3 * torch.randn(pred[:, : frame.shape[1] // 2].shape, generator=gen)
    ).clamp(0, 1)
    on, off = lpips(pred, frame, mask=left).item(), lpips(pred, frame, mask=1.0 - left).item()
    assert on > 2 * off > 0
    assert lpips(pred, frame, mask=0.5 * left).item() == pytest.approx(on, rel=1e-5)
    full = lpips(pred, frame, mask=torch.ones(frame.shape[:2])).item()
    assert full == pytest.approx(lpips(pred, frame).item(), rel=0.1)
    assert lpips(frame, frame, mask=left).item() == 0.0
    with pytest.raises(ValueError, match="mask must have"):
        lpips(pred, frame, mask=torch.ones(3, 3))


@needs_weights
def test_batch_matches_single(frame, degraded):
    preds = torch.stack(list(degraded.values()))
    batch = lpips(preds, frame.expand_as(preds))
    assert batch.shape == (3,)
    torch.testing.assert_close(batch, torch.stack([lpips(p, frame) for p in preds]), atol=1e-6, rtol=0)
    # the degradations rank as expected: small shift < blur < clamped noise
    assert batch[2] < batch[1] < batch[0]


@needs_weights
def test_legacy01_differs_from_pm1(frame, degraded):
    for pred in degraded.values():
        pm1 = lpips(pred, frame).item()
        legacy = lpips(pred, frame, scaling="legacy01").item()
        assert abs(pm1 - legacy) > 5e-3, (pm1, legacy)
        assert legacy < pm1  # on these frames the trap reports better (lower) numbers


@needs_weights
def test_gradients_flow_and_loss_descends(frame, gen):
    target = frame[32:96, 32:96]  # the textured centre of the frame
    pred = (target + 0.1 * torch.randn(target.shape, generator=gen)).requires_grad_()
    module = LPIPS()
    assert list(module.parameters()) == []
    opt = torch.optim.Adam([pred], lr=0.01)
    losses = []
    for _ in range(8):
        loss = module(pred, target)
        opt.zero_grad()
        loss.backward()
        assert pred.grad is not None and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0], losses


@needs_weights
def test_weights_loaded_once():
    lpips(torch.rand(32, 32, 3), torch.rand(32, 32, 3))
    before = _alex_state.cache_info()
    lpips(torch.rand(40, 40, 3), torch.rand(40, 40, 3))
    LPIPS(scaling="legacy01")
    after = _alex_state.cache_info()
    assert after.misses == before.misses and after.currsize == before.currsize == 1


def test_import_reads_no_weights():
    code = (
        "import sys, moegs.metrics as m; from moegs.metrics.lpips import _alex_state, _network; "
        "assert _alex_state.cache_info().currsize == 0 and _network.cache_info().currsize == 0; "
        "assert 'h5py' not in sys.modules and 'kornia' not in sys.modules and 'skimage' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_unavailable_weights_raise(monkeypatch, tmp_path, frame):
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path))
    assert not lpips_available()
    folder = tmp_path / "lpips_weights" / "lpips_tf" / "alex"
    with pytest.raises(
        LPIPSUnavailable, match=rf"^LPIPS-alex weights unavailable: looked in {folder}, missing slice_1"
    ):
        lpips(frame, frame)
    with pytest.raises(LPIPSUnavailable, match=rf"looked in {folder}"):
        LPIPS()


def test_exceptions(frame):
    with pytest.raises(ValueError, match=r"^lpips: unknown LPIPS net 'vgg'; valid nets: 'alex'"):
        lpips(frame, frame, net="vgg")
    with pytest.raises(
        ValueError, match=r"^lpips: unknown LPIPS scaling '01'; valid scalings: 'pm1', 'legacy01'$"
    ):
        lpips(frame, frame, scaling="01")
    with pytest.raises(ValueError, match=r"^lpips: `pred` must have 3 \(RGB\) channels, got 1$"):
        lpips(frame[..., :1], frame[..., :1])
    with pytest.raises(
        ValueError, match=r"^lpips: images must be at least 31x31 pixels for AlexNet, got 30x128$"
    ):
        lpips(frame[:30], frame[:30])
    with pytest.raises(ValueError, match=r"^LPIPS: unknown LPIPS scaling"):
        LPIPS(scaling="x")


@needs_weights
def test_building_the_network_draws_nothing_from_the_callers_generator():
    """A run scoring its first view mid-training must train on as it would have without: the network's
    layers are built (and their default initialisation drawn) under a forked generator."""
    from moegs.metrics.lpips import _network

    _network.cache_clear()
    torch.manual_seed(7)
    state = torch.get_rng_state()
    lpips(torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0)), torch.zeros(32, 32, 3))
    assert _network.cache_info().currsize == 1 and torch.equal(torch.get_rng_state(), state)
