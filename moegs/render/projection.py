"""EWA projection of 3D Gaussians and spherical-harmonic colours, in plain torch.

Shared by every backend and differentiated by autograd. Conventions follow ``moegs.camera``:
OpenCV camera (x right, y down, z forward) and pixel ``(x, y)`` centred at ``(x + 0.5, y + 0.5)``
in the image coordinates produced by ``K``.

Constants and where they come from:

* ``BLUR_3DGS = 0.3``: the low-pass filter of 3DGS (Kerbl et al. 2023, ``computeCov2D``), pixels²
  added to the diagonal of every 2D covariance; gsplat's ``eps2d`` default.
* ``DILATION_ANTIALIASED = 0.1``: the 2D filter of Ex4DGS (``diff_gaussian_rasterization_df``,
  ``kernel_size = 0.1``), the Mip-Splatting 2D filter (Yu et al. 2024) with opacity compensation
  ``sqrt(det(cov) / det(cov + 0.1 I))`` (Ex4DGS ``forward.cu:112-118`` clamps both determinants at
  1e-6 and adds 1e-6 under the root); equal to gsplat ``eps2d=0.1, rasterize_mode="antialiased"``.
* ``FOV_MARGIN = 1.3``: the Jacobian is evaluated at most 1.3 half-FoVs off the optical axis (3DGS).
  For an off-centre principal point each side gets its own limit, ``(visible extent) + 0.3 x half
  FoV``, which is the 3DGS rule when ``cx = W / 2`` (and gsplat's rule in general).
* ``RADIUS_SIGMAS = 3`` and ``EIGEN_GAP_FLOOR = 0.1``: 3DGS's screen radius
  ``ceil(3 sqrt(lambda_max))`` with ``lambda_max = mid + sqrt(max(0.1, mid² - det))``. The floor
  slightly inflates the radius of near-isotropic splats (e.g. 3 px instead of 2 px for a point seen
  through the 0.3 blur); it is kept because it decides which pixels a splat may touch.
* SH: the real SH basis constants of 3DGS (``auxiliary.h``) up to degree 3; colour is
  ``max(SH(dir) + 0.5, 0)`` with ``dir = normalize(mean - camera centre)``, as in 3DGS.

Quaternions are used as given, not normalised (the 3DGS CUDA kernel behaves the same way;
``GaussianFrame`` promises unit quaternions, and experts that feed non-unit ones, like Grid4D's
``normalize(q) + dr``, get the original behaviour).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from moegs.camera import Camera

BLUR_3DGS = 0.3
DILATION_ANTIALIASED = 0.1
FOV_MARGIN = 1.3
RADIUS_SIGMAS = 3.0
EIGEN_GAP_FLOOR = 0.1
_MAX_RADIUS = 2**30  # keeps the int32 cast of absurd radii defined; far above any image size

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


@dataclass
class Projection:
    """Screen-space Gaussians, ``N`` of them.

    Attributes:
        means2d: pixel coordinates ``[N, 2]``.
        conics: inverse 2D covariance ``(a, b, c)`` ``[N, 3]``.
        opacities: ``[N]``, multiplied by the compensation factor in antialiased mode.
        depths: camera-space z ``[N]``.
        radii: int32 ``[N]`` screen radius in pixels; 0 = culled.
    """

    means2d: Tensor
    conics: Tensor
    opacities: Tensor
    depths: Tensor
    radii: Tensor


# -- geometry ---------------------------------------------------------------------------------------
def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices ``[N, 3, 3]`` from quaternions ``[N, 4]`` (w, x, y, z), not normalised."""
    w, x, y, z = quats.unbind(-1)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariances ``R S S^T R^T`` ``[N, 3, 3]`` from quats ``[N, 4]`` and scales ``[N, 3]``.

    With ``M = R diag(s)``, entry ``(i, j)`` is ``(M_i0 M_j0 + M_i1 M_j1) + M_i2 M_j2``, element-wise in
    that order, which the compiled kernel (``moegs.render._cpu.covariance_3d``) reproduces to the bit."""
    rows = (quat_to_rotmat(quats) * scales[:, None, :]).unbind(-2)
    entry = [[rows[i][:, 0] * rows[j][:, 0] + rows[i][:, 1] * rows[j][:, 1] + rows[i][:, 2] * rows[j][:, 2]
              for j in range(3)] for i in range(3)]  # fmt: skip
    return torch.stack([torch.stack(row, dim=-1) for row in entry], dim=-2)


def camera_points(means: Tensor, camera: Camera) -> Tensor:
    """Camera-space positions ``[N, 3]`` of world points ``[N, 3]``.

    Element-wise in a fixed order (``((x r0 + y r1) + z r2) + t``), so the compiled projection
    (``moegs.render._cpu.project``) reproduces it to the bit."""
    w2c = camera.world_to_camera.to(means.dtype)
    x, y, z = means.unbind(-1)
    return torch.stack([x * w2c[i, 0] + y * w2c[i, 1] + z * w2c[i, 2] + w2c[i, 3] for i in range(3)], dim=-1)


def _jacobian_limits(camera: Camera) -> tuple[float, float, float, float]:
    """Clamp range ``(u_min, u_max, v_min, v_max)`` of ``x/z, y/z`` used in the EWA Jacobian."""
    margin_x = (FOV_MARGIN - 1.0) * camera.width / (2.0 * camera.fx)
    margin_y = (FOV_MARGIN - 1.0) * camera.height / (2.0 * camera.fy)
    return (
        -camera.cx / camera.fx - margin_x,
        (camera.width - camera.cx) / camera.fx + margin_x,
        -camera.cy / camera.fy - margin_y,
        (camera.height - camera.cy) / camera.fy + margin_y,
    )


def _covariance_2d(
    points: Tensor, covars: Tensor, depth: Tensor, camera: Camera
) -> tuple[Tensor, Tensor, Tensor]:
    """EWA screen covariance ``J W Σ W^T J^T`` as its entries ``(xx, xy, yy)``, each ``[N]`` (``depth``
    ``[N]`` is a safe z > 0). Element-wise products and sums in a fixed order (``J W``, then ``(J W) Σ``,
    then the three entries), which the compiled projection reproduces to the bit."""
    u_min, u_max, v_min, v_max = _jacobian_limits(camera)
    u = (points[:, 0] / depth).clamp(u_min, u_max)
    v = (points[:, 1] / depth).clamp(v_min, v_max)
    j00, j02 = camera.fx / depth, -camera.fx * u / depth  # J = [[j00, 0, j02], [0, j11, j12]]
    j11, j12 = camera.fy / depth, -camera.fy * v / depth
    r = camera.world_to_camera[:3, :3].to(points.dtype)
    t0 = [j00 * r[0, k] + j02 * r[2, k] for k in range(3)]  # rows of J W
    t1 = [j11 * r[1, k] + j12 * r[2, k] for k in range(3)]
    s = [[covars[:, m, k] for k in range(3)] for m in range(3)]
    p0 = [t0[0] * s[0][k] + t0[1] * s[1][k] + t0[2] * s[2][k] for k in range(3)]  # rows of (J W) Σ
    p1 = [t1[0] * s[0][k] + t1[1] * s[1][k] + t1[2] * s[2][k] for k in range(3)]
    xx = p0[0] * t0[0] + p0[1] * t0[1] + p0[2] * t0[2]
    xy = p0[0] * t1[0] + p0[1] * t1[1] + p0[2] * t1[2]
    yy = p1[0] * t1[0] + p1[1] * t1[1] + p1[2] * t1[2]
    return xx, xy, yy


def _sqrt(x: Tensor) -> Tensor:
    """Correctly rounded square root: torch's float32 ``sqrt`` on CPU is not (up to 1 ulp off); taken in
    float64 and rounded back it is, so the compiled projection's ``sqrtf`` matches it to the bit."""
    return torch.sqrt(x.double()).to(x.dtype) if x.dtype == torch.float32 else torch.sqrt(x)


def _screen_radii(a: Tensor, b: Tensor, c: Tensor, det: Tensor) -> Tensor:
    """3DGS radius ``ceil(3 sqrt(lambda_max))`` ``[N]`` (float) of blurred 2D covariances ``(a, b, c)``."""
    mid = 0.5 * (a + c)
    lambda_max = mid + _sqrt(torch.clamp(mid * mid - det, min=EIGEN_GAP_FLOOR))
    return torch.ceil(RADIUS_SIGMAS * _sqrt(lambda_max))


def project(
    means: Tensor,  # [N, 3]
    covars: Tensor,  # [N, 3, 3]
    opacities: Tensor,  # [N]
    camera: Camera,
    *,
    eps2d: float = BLUR_3DGS,
    antialiased: bool = False,
) -> Projection:
    """EWA-project Gaussians to the screen of ``camera``.

    ``eps2d`` (pixels²) is added to the diagonal of each 2D covariance. With ``antialiased`` the
    opacity is also multiplied by ``sqrt(det(cov) / det(cov + eps2d I))`` (Mip-Splatting, Ex4DGS);
    pass ``eps2d=DILATION_ANTIALIASED`` for Ex4DGS's filter.

    Culled (radius 0): ``z <= near`` or ``z >= far``; non-positive or non-finite ``det`` of the
    blurred covariance; a ``[mean - r, mean + r]`` box that misses the image ``[0, W] x [0, H]``.
    Culled Gaussians get finite placeholder values and zero gradients.
    """
    points = camera_points(means, camera)
    z = points[:, 2]
    in_depth = (z > camera.near) & (z < camera.far)
    depth = torch.where(in_depth, z, torch.ones_like(z))  # safe divisor for the culled ones
    means2d = torch.stack(
        [camera.fx * points[:, 0] / depth + camera.cx, camera.fy * points[:, 1] / depth + camera.cy], dim=-1
    )

    raw_a, b, raw_c = _covariance_2d(points, covars, depth, camera)
    a, c = raw_a + eps2d, raw_c + eps2d
    det = a * c - b * b
    valid = in_depth & torch.isfinite(det) & (det > 0)
    safe_det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c, -b, a], dim=-1) / safe_det[:, None]
    conics = torch.where(valid[:, None], conics, torch.zeros_like(conics))

    if antialiased:
        raw_det = raw_a * raw_c - b * b
        positive = valid & (raw_det > 0)
        ratio = torch.where(positive, raw_det / safe_det, torch.ones_like(det))
        opacities = opacities * torch.where(positive, _sqrt(ratio), torch.zeros_like(det))

    with torch.no_grad():
        radius = torch.where(valid, _screen_radii(a, b, c, safe_det), torch.zeros_like(det))
        radius = radius.clamp(max=_MAX_RADIUS)
        mx, my = means2d[:, 0], means2d[:, 1]
        on_screen = (
            (mx + radius > 0)
            & (mx - radius < camera.width)
            & (my + radius > 0)
            & (my - radius < camera.height)
        )
        radii = torch.where(valid & on_screen, radius, torch.zeros_like(radius)).to(torch.int32)
    return Projection(means2d=means2d, conics=conics, opacities=opacities, depths=z, radii=radii)


# -- spherical harmonics --------------------------------------------------------------------------
def sh_basis(dirs: Tensor, degree: int) -> Tensor:
    """Real SH basis ``[N, (degree + 1)^2]`` at unit directions ``[N, 3]`` (3DGS constants and signs)."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be in 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        basis += [
            SH_C3[0] * y * (3 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(basis, dim=-1)


def view_dirs(means: Tensor, camera: Camera) -> Tensor:
    """Unit directions ``[N, 3]`` from the camera centre to each mean ``[N, 3]``."""
    return torch.nn.functional.normalize(means - camera.center.to(means.dtype), dim=-1)


def rgb_to_sh0(rgb: Tensor) -> Tensor:
    """RGB ``[..., 3]`` in [0, 1] -> SH DC coefficient (3DGS ``RGB2SH``)."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: Tensor) -> Tensor:
    """Inverse of :func:`rgb_to_sh0` (3DGS ``SH2RGB``)."""
    return sh0 * SH_C0 + 0.5


def eval_sh(sh: Tensor, dirs: Tensor, degree: int) -> Tensor:
    """Colours ``max(SH(dir) + 0.5, 0)`` ``[N, C]`` from coefficients ``[N, B, C]`` and unit dirs ``[N, 3]``.

    Uses the first ``(degree + 1)^2`` of the ``B`` bases.
    """
    bases = (degree + 1) ** 2
    if sh.shape[1] < bases:
        raise ValueError(f"SH degree {degree} needs {bases} bases, the coefficients have {sh.shape[1]}")
    values = torch.einsum("nb,nbc->nc", sh_basis(dirs, degree), sh[:, :bases])
    return torch.clamp_min(values + 0.5, 0.0)
