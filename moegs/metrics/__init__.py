"""Image metrics (PSNR, SSIM variants, LPIPS), metric profiles and the speed/memory protocol.

Image convention for every metric: channels-last floats in [0, 1], one image ``[H, W, C]`` (as
``rasterize`` returns it) -> 0-dim result, or a batch ``[B, H, W, C]`` -> ``[B]``. Importing this
package reads no weights; LPIPS loads them on first use.
"""

from moegs.metrics.lpips import LPIPS, LPIPS_NETS, LPIPS_SCALINGS, LPIPSUnavailable, lpips, lpips_available
from moegs.metrics.profile import PROFILES, MetricProfile, evaluate_images, get_profile
from moegs.metrics.psnr import psnr
from moegs.metrics.speed import SpeedResult, measure_render
from moegs.metrics.ssim import SSIM, SSIM_VARIANTS, ssim, ssim_map

__all__ = [
    "LPIPS",
    "LPIPS_NETS",
    "LPIPS_SCALINGS",
    "PROFILES",
    "SSIM",
    "SSIM_VARIANTS",
    "LPIPSUnavailable",
    "MetricProfile",
    "SpeedResult",
    "evaluate_images",
    "get_profile",
    "lpips",
    "lpips_available",
    "measure_render",
    "psnr",
    "ssim",
    "ssim_map",
]
