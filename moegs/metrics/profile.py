"""Named metric profiles: which PSNR/SSIM/LPIPS conventions a number was computed with.

Every results JSON records ``MetricProfile.to_dict()`` (name, id and all settings), because the
conventions move the third decimal and cross-paper numbers only compare under the same profile.

Presets:

- ``"moegs"``: what the MoE-GS/MoDE evaluation code does (``render_E4.py``, ``render_E3_tech.py``,
  ``render_emb.py``; see ``specs/official_moegs.md`` section 8 and ``peers_and_style.md`` C.1):
  PSNR ``20 log10(1/sqrt(MSE))`` on the *unclamped* float render, no 8-bit round trip; the 3DGS
  zero-padded SSIM; ``lpipsPyTorch.lpips(x, y, net_type="alex")``, whose forward only applies the
  LPIPS scaling layer to the [0, 1] render, hence "legacy01". lpipsPyTorch itself is absent from
  the archived MoE-GS copy; every 3DGS-lineage copy (3DGS, 4DGaussians, E-D3DGS, STG, Ex4DGS) has
  no rescaling, so "legacy01" is the inference, not a line read in MoE-GS. Its batch sum is
  irrelevant (called per frame). ROI numbers use the mask-normalised ``psnr(..., mask)``
  (``utils/image_utils.py::m_psnr``). Use this profile to compare with the paper's tables.
- ``"clean"``: the corrected protocol: render clamped to [0, 1], 3DGS SSIM, LPIPS-alex on inputs
  rescaled to [-1, 1]. Use it for new comparisons; it is not comparable with the paper's LPIPS.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from torch import Tensor

from moegs.metrics._images import quantize_u8
from moegs.metrics.lpips import LPIPS_NETS, LPIPS_SCALINGS, LPIPSUnavailable, lpips
from moegs.metrics.psnr import psnr
from moegs.metrics.ssim import SSIM_VARIANTS, ssim


@dataclass(frozen=True)
class MetricProfile:
    """How PSNR, SSIM and LPIPS are computed for one results table."""

    name: str
    """Preset name recorded in results ("moegs", "clean", or a custom one)."""
    ssim_variant: str = "3dgs"
    """Key of ``SSIM_VARIANTS``."""
    lpips_net: str = "alex"
    """LPIPS backbone (``LPIPS_NETS``)."""
    lpips_scaling: str = "pm1"
    """"pm1" (correct) or "legacy01" (3DGS-lineage [0, 1] inputs)."""
    clamp: bool = True
    """Clamp the prediction to [0, 1] before every metric."""
    quantize_u8: bool = False
    """Round prediction and target to the 8-bit grid first (metrics from saved PNGs); implies clamping."""

    def __post_init__(self) -> None:
        if self.ssim_variant not in SSIM_VARIANTS:
            raise ValueError(f"MetricProfile.ssim_variant {self.ssim_variant!r} not in {list(SSIM_VARIANTS)}")
        if self.lpips_net not in LPIPS_NETS:
            raise ValueError(f"MetricProfile.lpips_net {self.lpips_net!r} not in {list(LPIPS_NETS)}")
        if self.lpips_scaling not in LPIPS_SCALINGS:
            raise ValueError(
                f"MetricProfile.lpips_scaling {self.lpips_scaling!r} not in {list(LPIPS_SCALINGS)}"
            )

    @property
    def id(self) -> str:
        """Self-describing id, e.g. ``moegs/psnr_raw-ssim_3dgs-lpips_alex_legacy01``."""
        pixels = "u8" if self.quantize_u8 else ("clamp" if self.clamp else "raw")
        return (
            f"{self.name}/psnr_{pixels}-ssim_{self.ssim_variant}-lpips_{self.lpips_net}_{self.lpips_scaling}"
        )

    def to_dict(self) -> dict:
        return {"id": self.id, **asdict(self)}


PROFILES: dict[str, MetricProfile] = {
    "moegs": MetricProfile(
        "moegs", ssim_variant="3dgs", lpips_net="alex", lpips_scaling="legacy01", clamp=False
    ),
    "clean": MetricProfile("clean", ssim_variant="3dgs", lpips_net="alex", lpips_scaling="pm1", clamp=True),
}


def get_profile(profile: str | MetricProfile) -> MetricProfile:
    """A preset by name, or the given profile unchanged."""
    if isinstance(profile, MetricProfile):
        return profile
    if profile not in PROFILES:
        raise ValueError(
            f"unknown metric profile {profile!r}; valid profiles: {', '.join(map(repr, PROFILES))}"
        )
    return PROFILES[profile]


def evaluate_images(
    pred: Tensor, target: Tensor, profile: str | MetricProfile = "moegs", mask: Tensor | None = None
) -> dict:
    """PSNR, SSIM and LPIPS of ``pred`` against ``target`` under one profile.

    Args:
        pred: render ``[H, W, C]`` or ``[B, H, W, C]`` in [0, 1] (C = 3 for LPIPS).
        target: ground truth, same shape.
        profile: preset name or ``MetricProfile``.
        mask: optional ROI ``[H, W]``/``[H, W, 1]``/``[H, W, C]`` (leading ``B`` when batched): PSNR is
            mask-normalised, SSIM and LPIPS the mask-weighted means of their spatial maps.

    Returns:
        ``{"psnr", "ssim", "lpips", "lpips_unavailable", "masked", "profile"}``; values are floats for
        one image and lists of per-image floats for a batch; ``lpips`` is ``None`` exactly when
        ``lpips_unavailable`` holds the reason; ``profile`` is ``MetricProfile.to_dict()``.
    """
    prof = get_profile(profile)
    if prof.quantize_u8:
        pred, target = quantize_u8(pred), quantize_u8(target)
    elif prof.clamp:
        pred = pred.clamp(0.0, 1.0)
    pred, target = pred.detach(), target.detach()

    def plain(t: Tensor) -> float | list[float]:
        return t.tolist() if t.ndim else t.item()

    out = {
        "psnr": plain(psnr(pred, target, mask)),
        "ssim": plain(ssim(pred, target, prof.ssim_variant, mask)),
        "lpips": None,
        "lpips_unavailable": None,
        "masked": mask is not None,
    }
    roi = None if mask is None else (mask if mask.ndim == pred.ndim - 1 else mask[..., 0])
    try:
        out["lpips"] = plain(lpips(pred, target, prof.lpips_net, prof.lpips_scaling, mask=roi))
    except LPIPSUnavailable as exc:
        out["lpips_unavailable"] = str(exc)
    out["profile"] = prof.to_dict()
    return out
