"""Pinhole camera shared by data loaders, experts, the rasterizer and the routers.

Conventions (OpenCV / COLMAP): camera x right, y down, z forward; ``world_to_camera`` maps world
points to camera coordinates; pixel (x, y) has its centre at (x + 0.5, y + 0.5) in the image
coordinates produced by ``K``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

ROTATION_TOLERANCE = 1e-3
"""Largest entry of ``|R^T R - I|`` a camera rotation may have: datasets store poses in float32 or to six
decimals (D-NeRF's mutant: 5e-6; Panoptic's basketball: 1e-10); a scaled or sheared matrix is far off."""


def rotation_problem(R: Tensor) -> str:
    """What keeps ``R [3, 3]`` from being a rotation, or "" when it is one: singular, not orthonormal
    within ``ROTATION_TOLERANCE``, or a reflection (determinant -1: the camera would see a mirror image)."""
    R = R.detach().cpu().double()
    det = float(torch.linalg.det(R))
    if abs(det) < 1e-9:
        return "is singular"
    error = float((R.T @ R - torch.eye(3, dtype=torch.float64)).abs().max())
    if error > ROTATION_TOLERANCE:
        tolerance = f"tolerance {ROTATION_TOLERANCE:g}"
        return f"is not orthonormal (largest entry of |R^T R - I|: {error:.3g}; {tolerance})"
    if det < 0:
        return "is a reflection (determinant -1), not a rotation: the camera would see the scene mirrored"
    return ""


@dataclass(frozen=True)
class Camera:
    """One view at one time.

    Attributes:
        K: intrinsics ``[3, 3]``.
        world_to_camera: extrinsics ``[4, 4]`` (OpenCV convention).
        width, height: image size in pixels.
        time: normalised time in [0, 1] used by the experts (dataset-specific convention).
        near, far: clipping distances along the optical axis.
        camera_id: index of the physical camera (per-camera terms, e.g. E-D3DGS's time offset).
        frame: integer frame index within the scene (``-1`` if not applicable).
        name: identifier used in logs and outputs (e.g. ``cam00/0012``).

    The intrinsics are also kept as Python floats (``fx``, ``fy``, ``cx``, ``cy``), read once when the
    camera is made, so a camera on a GPU answers them without waiting for the device; ``to``,
    ``at_time`` and ``with_planes`` carry them (and the checks already passed) over.
    """

    K: Tensor
    world_to_camera: Tensor
    width: int
    height: int
    time: float = 0.0
    near: float = 0.01
    far: float = 1000.0
    camera_id: int = 0
    frame: int = -1
    name: str = ""
    _intrinsics: tuple[float, float, float, float] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if tuple(self.K.shape) != (3, 3):
            raise ValueError(f"Camera.K must have shape [3, 3], got {list(self.K.shape)}")
        if tuple(self.world_to_camera.shape) != (4, 4):
            raise ValueError(
                f"Camera.world_to_camera must have shape [4, 4], got {list(self.world_to_camera.shape)}"
            )
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")
        if not (0.0 < self.near < self.far):
            raise ValueError(f"Camera needs 0 < near < far, got near={self.near}, far={self.far}")
        if self._intrinsics is None:  # a new camera: check its values once, on the host
            object.__setattr__(self, "_intrinsics", self._checked_intrinsics())

    def _checked_intrinsics(self) -> tuple[float, float, float, float]:
        K, w2c = self.K.detach().cpu(), self.world_to_camera.detach().cpu()
        if not torch.isfinite(K).all() or not torch.isfinite(w2c).all():
            raise ValueError(f"Camera {self.name!r} has non-finite intrinsics or extrinsics")
        fx, fy = float(K[0, 0]), float(K[1, 1])
        if not (fx > 0 and fy > 0):
            raise ValueError(f"Camera {self.name!r} needs positive focal lengths, got fx={fx}, fy={fy}")
        problem = rotation_problem(w2c[:3, :3])
        if problem:
            raise ValueError(f"Camera {self.name!r}: its world_to_camera rotation {problem}")
        return fx, fy, float(K[0, 2]), float(K[1, 2])

    # -- derived quantities -------------------------------------------------------------------
    @property
    def device(self) -> torch.device:
        return self.K.device

    @property
    def fx(self) -> float:
        return self._intrinsics[0]

    @property
    def fy(self) -> float:
        return self._intrinsics[1]

    @property
    def cx(self) -> float:
        return self._intrinsics[2]

    @property
    def cy(self) -> float:
        return self._intrinsics[3]

    @property
    def camera_to_world(self) -> Tensor:
        """``[4, 4]`` inverse of ``world_to_camera``."""
        return torch.linalg.inv(self.world_to_camera)

    @property
    def center(self) -> Tensor:
        """Camera centre in world coordinates, ``[3]``."""
        R, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -R.T @ t

    def rays(self) -> tuple[Tensor, Tensor]:
        """Per-pixel rays through pixel centres.

        Returns:
            origins ``[H, W, 3]`` (the camera centre) and unit directions ``[H, W, 3]`` in world space.
        """
        dtype, device = self.K.dtype, self.K.device
        ys, xs = torch.meshgrid(
            torch.arange(self.height, dtype=dtype, device=device) + 0.5,
            torch.arange(self.width, dtype=dtype, device=device) + 0.5,
            indexing="ij",
        )
        pix = torch.stack([xs, ys, torch.ones_like(xs)], dim=-1)  # [H, W, 3]
        dirs_cam = pix @ torch.linalg.inv(self.K).T
        R = self.world_to_camera[:3, :3]
        dirs = torch.nn.functional.normalize(dirs_cam @ R, dim=-1)  # R^T d, row-vector form
        origins = self.center.expand_as(dirs)
        return origins, dirs

    # -- transforms ---------------------------------------------------------------------------
    def scaled(self, factor: float) -> Camera:
        """The same camera with the image resized by ``factor`` (e.g. 0.5 for half resolution)."""
        if factor <= 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        K = self.K.clone()
        K[:2] *= factor
        return replace(
            self, K=K, width=round(self.width * factor), height=round(self.height * factor), _intrinsics=None
        )

    def to(self, device: torch.device | str) -> Camera:
        """The same camera with its tensors on ``device`` (itself when they are there already)."""
        if self.K.device == torch.device(device) and self.world_to_camera.device == torch.device(device):
            return self
        return replace(self, K=self.K.to(device), world_to_camera=self.world_to_camera.to(device))

    def at_time(self, time: float) -> Camera:
        return replace(self, time=float(time))

    def with_planes(self, near: float, far: float) -> Camera:
        """The same camera with other clipping distances."""
        return replace(self, near=near, far=far)

    def pose_key(self) -> bytes:
        """The camera apart from its time: intrinsics, pose and image size, as hashable bytes."""
        k = self.K.detach().to("cpu", torch.float64).numpy().tobytes()
        w2c = self.world_to_camera.detach().to("cpu", torch.float64).numpy().tobytes()
        return k + w2c + f"{self.width}x{self.height}".encode()


def look_at(eye: Tensor, target: Tensor, up: Tensor | None = None) -> Tensor:
    """World-to-camera ``[4, 4]`` (OpenCV) for a camera at ``eye`` looking at ``target``.

    ``up`` is the world up vector (default +z); the camera's y axis points opposite to it.
    """
    eye, target = eye.to(torch.float32), target.to(torch.float32)
    up = torch.tensor([0.0, 0.0, 1.0]) if up is None else up.to(torch.float32)
    z = torch.nn.functional.normalize(target - eye, dim=0)
    x = torch.nn.functional.normalize(torch.linalg.cross(z, up), dim=0)
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z], dim=0)  # rows: camera axes in world coordinates
    w2c = torch.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> Tensor:
    """``[3, 3]`` pinhole intrinsics."""
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float32)
