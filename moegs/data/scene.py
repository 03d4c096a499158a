"""One ``Scene`` object for every dataset: views (camera + lazily loaded image), time, bounds, points.

Loaders (``dnerf``, ``panoptic``, ``n3v``, ``technicolor``, ``hypernerf``, ``synthetic``) build a
``Scene``; experts, trainers and the harness consume only this.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field, replace
from typing import Any

import torch
from torch import Tensor

from moegs.camera import Camera


def tensor_bytes(value: Tensor) -> int:
    """Memory held by one tensor's elements."""
    return value.numel() * value.element_size()


class ImageCache:
    """LRU cache of decoded images (8-bit ones as uint8), shared by all views of a scene, bounded by
    ``max_bytes`` (default 1 GiB: every training view of the quick and standard presets stays resident)
    and optionally by ``max_items``; 0 for either keeps nothing. ``nbytes`` sizes a value (other values
    than one tensor: e.g. a frozen expert's rasterizer inputs, ``moegs.moe.train``)."""

    def __init__(
        self,
        max_items: int | None = None,
        max_bytes: int = 1 << 30,
        nbytes: Callable[[Any], int] = tensor_bytes,
    ) -> None:
        self.max_items = max_items
        self.max_bytes = max_bytes
        self.nbytes = nbytes
        self.bytes = 0
        self._items: OrderedDict[Hashable, Any] = OrderedDict()

    def get(self, key: Hashable, load: Callable[[], Any]) -> Any:
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        value = load()
        size = self.nbytes(value)
        if self.max_items == 0 or size > self.max_bytes:
            return value
        self._items[key] = value
        self.bytes += size
        too_many = self.max_items is not None and len(self._items) > self.max_items
        while self.bytes > self.max_bytes or too_many:
            _, old = self._items.popitem(last=False)
            self.bytes -= self.nbytes(old)
            too_many = self.max_items is not None and len(self._items) > self.max_items
        return value

    def __len__(self) -> int:
        return len(self._items)


DEVICE_IMAGE_SHARE = 0.4
"""Share of a GPU's memory that a placed scene's images may hold (``Scene.to``); beyond it the least
recently used are dropped and copied again from the host when needed. ``MOEGS_DEVICE_IMAGE_BYTES``
sets the bytes instead. N3V's 19 cameras x 300 frames at 1352x1014 are 23 GB as 8-bit images."""


def device_image_bytes(device: torch.device) -> int:
    """Bytes of images a scene placed on ``device`` keeps there (see ``DEVICE_IMAGE_SHARE``)."""
    override = os.environ.get("MOEGS_DEVICE_IMAGE_BYTES")
    if override:
        try:
            return int(override)
        except ValueError:
            message = f"MOEGS_DEVICE_IMAGE_BYTES: expected a number of bytes, got {override!r}"
            raise ValueError(message) from None
    if device.type != "cuda":
        return 1 << 30
    return int(DEVICE_IMAGE_SHARE * torch.cuda.get_device_properties(device).total_memory)


@dataclass
class View:
    """A camera with its ground truth, loaded on demand.

    Attributes:
        camera: the camera (carries ``time``, ``frame`` and ``camera_id``).
        load_image: returns the image ``[H, W, 3]`` at the camera's resolution, already composited on
            the scene background: uint8 as decoded (real data) or float32 in [0, 1] (rendered stand-ins).
            The scene's cache keeps what it returns, so 8-bit images stay resident at a byte a value.
        load_mask: optional, returns a mask ``[H, W]`` float32 in [0, 1] (e.g. dynamic region).
        key: unique identifier used by the cache and in per-view results.
        load_regions: optional, returns named masks ``{name: [H, W]}`` float32 in {0, 1}, the same names for
            every view of a scene (a stand-in's motion regimes: the pixels of its ``articulated``,
            ``transient``... objects); evaluations score each region separately.
    """

    camera: Camera
    load_image: Callable[[], Tensor]
    key: str
    load_mask: Callable[[], Tensor] | None = None
    cache: ImageCache | None = field(default=None, repr=False)
    load_regions: Callable[[], dict[str, Tensor]] | None = None

    def stored_image(self) -> Tensor:
        """The image as loaded (uint8 or float32 ``[H, W, 3]``), through the scene's cache."""
        return self.load_image() if self.cache is None else self.cache.get(self.key, self.load_image)

    def image(self) -> Tensor:
        """``[H, W, 3]`` float32 in [0, 1] (on the camera's device in a placed scene, ``Scene.to``)."""
        image = self.stored_image()
        return image.to(torch.float32) / 255.0 if image.dtype == torch.uint8 else image

    def to(self, device: torch.device) -> View:
        """This view with its camera on ``device`` and its image, mask and regions copied there when read;
        the image comes from this view's cache (decoded once) and is kept by the placed scene's cache."""
        return replace(
            self,
            camera=self.camera.to(device),
            load_image=lambda: self.stored_image().to(device, non_blocking=True),
            load_mask=None if self.load_mask is None else lambda: self.load_mask().to(device),
            load_regions=None
            if self.load_regions is None
            else lambda: {k: v.to(device) for k, v in self.load_regions().items()},
            cache=None,
        )

    def mask(self) -> Tensor | None:
        return None if self.load_mask is None else self.load_mask()

    def regions(self) -> dict[str, Tensor]:
        """Named region masks (empty without ``load_regions``)."""
        return {} if self.load_regions is None else self.load_regions()


@dataclass
class PointCloud:
    """Initial points ``xyz [P, 3]`` and colours ``rgb [P, 3]`` in [0, 1]; ``source`` says how they were
    made."""

    xyz: Tensor
    rgb: Tensor
    source: str = "unknown"
    times: Tensor | None = None  # [P] normalised time of each point (STG-style per-frame clouds)

    def __post_init__(self) -> None:
        if self.xyz.ndim != 2 or self.xyz.shape[1] != 3:
            raise ValueError(f"PointCloud.xyz must have shape [P, 3], got {list(self.xyz.shape)}")
        if self.rgb.shape != self.xyz.shape:
            raise ValueError(
                f"PointCloud.rgb must have shape {list(self.xyz.shape)}, got {list(self.rgb.shape)}"
            )
        if not torch.isfinite(self.xyz).all():
            raise ValueError(f"PointCloud.xyz ({self.source}) contains NaN or Inf")

    def __len__(self) -> int:
        return self.xyz.shape[0]


@dataclass
class Scene:
    """A dynamic scene.

    Attributes:
        name: registry name, e.g. ``dnerf:mutant``.
        dataset: ``dnerf`` | ``panoptic`` | ``n3v`` | ``technicolor`` | ``hypernerf`` | ``synthetic``.
        train, test: views; each camera's ``time`` is normalised to [0, 1].
        num_frames: number of distinct time steps.
        background: ``[3]`` colour the ground truth is composited on.
        bbox: ``[2, 3]`` axis-aligned bounds (min, max) of the content.
        extent: scene radius used to scale densification thresholds (3DGS ``cameras_extent``).
        points: initial point cloud, or ``None`` when the dataset has none (see ``moegs.data.points``).
        multiview: True when several cameras see each time step.
        stand_in: text saying what real data this scene stands in for ("" for real data).
        meta: dataset-specific facts the loader read or chose (frame window, time convention,
            near/far bounds, ignored distortion, ...); JSON-serialisable values only.
    """

    name: str
    dataset: str
    train: list[View]
    test: list[View]
    num_frames: int
    background: Tensor
    bbox: Tensor
    extent: float
    points: PointCloud | None = None
    multiview: bool = False
    stand_in: str = ""
    meta: dict = field(default_factory=dict)
    cache: ImageCache = field(default_factory=ImageCache, repr=False)
    _placed: dict[torch.device, Scene] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.train:
            raise ValueError(f"scene {self.name!r} has no training views")
        for view in [*self.train, *self.test]:
            view.cache = self.cache

    def to(self, device: torch.device | str) -> Scene:
        """This scene for a run on ``device``: itself on the CPU; elsewhere a copy (made once per device)
        whose cameras and background live there and whose images are copied there when first read and
        kept in a cache of ``device_image_bytes(device)`` (8-bit images stay 8-bit). Initial points and
        bounds stay on the CPU, where experts are built."""
        device = torch.device(device)
        here = self.background.device
        if here.type == device.type and (here.index or 0) == (device.index or 0):
            return self  # a scene on the CPU, or one placed on ``device`` already
        if device not in self._placed:
            self._placed[device] = replace(
                self,
                train=[v.to(device) for v in self.train],
                test=[v.to(device) for v in self.test],
                background=self.background.to(device),
                cache=ImageCache(max_bytes=device_image_bytes(device)),
            )
        return self._placed[device]

    @property
    def times(self) -> Tensor:
        """Sorted distinct normalised times of the training views ``[T]``."""
        return torch.tensor(sorted({v.camera.time for v in self.train}), dtype=torch.float32)

    @property
    def is_real(self) -> bool:
        return not self.stand_in

    def identity(self) -> dict[str, Any]:
        """What a checkpoint records of the scene it trained on: name, dataset, number of training and
        test views, frames and the training image size ``[width, height]``."""
        cam = self.train[0].camera
        return {
            "name": self.name,
            "dataset": self.dataset,
            "train_views": len(self.train),
            "test_views": len(self.test),
            "frames": self.num_frames,
            "size": [cam.width, cam.height],
        }

    def check_identity(self, saved: dict[str, Any] | None, path: Any, fields: tuple[str, ...] = ()) -> None:
        """Refuse a checkpoint at ``path`` whose recorded scene identity (``saved``) is not this scene's:
        its name and dataset, and ``fields`` of ``identity`` as well (a resumed run checks them all). A
        checkpoint written before identities were recorded (``saved`` None) is accepted."""
        if saved is None:
            return
        mine = self.identity()
        differ = [k for k in ("name", "dataset", *fields) if saved.get(k) != mine[k]]
        if differ:
            theirs = ", ".join(f"{k} {saved.get(k)!r}" for k in differ)
            ours = ", ".join(f"{k} {mine[k]!r}" for k in differ)
            raise ValueError(f"{path} was trained on another scene ({theirs}), not this one ({ours})")

    def summary(self) -> str:
        cam = self.train[0].camera
        return (
            f"{self.name}: {len(self.train)} train / {len(self.test)} test views, {self.num_frames} frames, "
            f"{cam.width}x{cam.height}, {'multi' if self.multiview else 'mono'}-view"
            + (f", stand-in for {self.stand_in}" if self.stand_in else "")
        )
