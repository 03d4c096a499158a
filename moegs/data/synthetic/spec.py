"""What to generate: ``SyntheticSpec`` presets per named scene and the generation hash."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields, replace

# Bump when the renderer, the scenes or the writers change what is written for the same spec.
GENERATOR_VERSION = 3

LAYOUTS = ("n3v", "dnerf")
CODECS = ("lossless", "yuv444", "yuv420")


@dataclass(frozen=True)
class SyntheticSpec:
    """A synthetic scene generation.

    Attributes:
        scene: procedural scene description (``moegs.data.synthetic.scenes.SCENES``).
        layout: ``n3v`` (poses_bounds.npy + camXX.mp4) or ``dnerf`` (transforms_*.json + RGBA PNGs).
        stand_in_for: the real dataset this scene stands in for (``Scene.stand_in``).
        width, height: image size in pixels.
        num_frames: n3v: frames per camera (frame i at time i / num_frames, the N3V ``frame/300``
            convention); dnerf: training time steps (times ``linspace(0, 1)``).
        num_cameras: n3v: cameras including the held-out ``cam00``.
        num_val, num_test: dnerf: views at held-out times and angles.
        hfov_deg: horizontal field of view.
        supersample: stratified rays per pixel side for colour and alpha (depth/ids use the centre ray).
        fps: n3v video frame rate.
        codec: n3v videos: ``lossless`` (libx264rgb qp 0, bit-exact), ``yuv444`` (libx264 qp 0, about
            52 dB on noise) or ``yuv420`` (libx264 crf 18, like real N3V videos; needs even sizes).
        rig_span: n3v: width of the camera rig in metres.
        orbit_radius: dnerf: camera distance to the target.
        triangulate: n3v: write ``points3D.ply`` triangulated by pycolmap from frame 0 of the training
            cameras (the sparse COLMAP step of the N3V pipelines).
        dense_points: n3v: write ``points3D_downsample2.ply``, frame 0 of the training cameras back-projected
            with the ground-truth depth and voxel-downsampled to at most this many points (0: none): the
            analytic counterpart of 4DGaussians' dense MVS cloud, which the N3V loader prefers.
    """

    scene: str
    layout: str
    stand_in_for: str
    width: int
    height: int
    num_frames: int
    num_cameras: int = 0
    num_val: int = 0
    num_test: int = 0
    hfov_deg: float = 65.0
    supersample: int = 2
    fps: int = 30
    codec: str = "lossless"
    rig_span: float = 2.0
    orbit_radius: float = 4.5
    triangulate: bool = True
    dense_points: int = 40_000

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ValueError(f"SyntheticSpec.layout must be one of {LAYOUTS}, got {self.layout!r}")
        if self.codec not in CODECS:
            raise ValueError(f"SyntheticSpec.codec must be one of {CODECS}, got {self.codec!r}")
        if self.width < 8 or self.height < 8:
            raise ValueError(f"SyntheticSpec: image too small ({self.width}x{self.height}), need >= 8x8")
        if self.supersample < 1:
            raise ValueError(f"SyntheticSpec.supersample must be >= 1, got {self.supersample}")
        if self.num_frames < 2:
            raise ValueError(f"SyntheticSpec.num_frames must be >= 2, got {self.num_frames}")
        if self.layout == "n3v" and self.num_cameras < 3:
            raise ValueError(
                f"n3v layout needs num_cameras >= 3 (cam00 test + 2 train), got {self.num_cameras}"
            )
        if self.layout == "dnerf" and self.num_test < 1:
            raise ValueError(f"dnerf layout needs num_test >= 1, got {self.num_test}")
        if self.codec == "yuv420" and (self.width % 2 or self.height % 2):
            raise ValueError(f"codec 'yuv420' needs even image sizes, got {self.width}x{self.height}")

    def with_overrides(self, **overrides) -> SyntheticSpec:
        valid = {f.name for f in fields(self)}
        bad = sorted(set(overrides) - valid)
        if bad:
            raise TypeError(f"unknown SyntheticSpec field(s) {bad}; valid: {sorted(valid)}")
        return replace(self, **overrides)


PRESETS: dict[str, dict[str, SyntheticSpec]] = {
    "n3v_like": {
        "quick": SyntheticSpec("n3v_like", "n3v", "N3V", width=128, height=96, num_frames=16, num_cameras=8),
        "paper": SyntheticSpec(
            "n3v_like", "n3v", "N3V", width=480, height=360, num_frames=300, num_cameras=18
        ),
    },
    "dnerf_like": {
        "quick": SyntheticSpec(
            "dnerf_like",
            "dnerf",
            "D-NeRF",
            width=100,
            height=100,
            num_frames=50,
            num_val=5,
            num_test=5,
            hfov_deg=39.6,
            orbit_radius=3.4,
        ),
        "paper": SyntheticSpec(
            "dnerf_like",
            "dnerf",
            "D-NeRF",
            width=400,
            height=400,
            num_frames=150,
            num_val=20,
            num_test=20,
            hfov_deg=39.6,
            orbit_radius=3.4,
        ),
    },
}


def get_spec(name: str, preset: str = "quick", **overrides) -> SyntheticSpec:
    """The preset spec of a named synthetic scene, with optional field overrides."""
    if name not in PRESETS:
        raise KeyError(f"unknown synthetic scene {name!r}; valid: {sorted(PRESETS)}")
    if preset not in PRESETS[name]:
        raise KeyError(
            f"unknown preset {preset!r} for synthetic scene {name!r}; valid: {sorted(PRESETS[name])}"
        )
    spec = PRESETS[name][preset]
    return spec.with_overrides(**overrides) if overrides else spec


def spec_hash(spec: SyntheticSpec, seed: int) -> str:
    """sha256 of the spec, the seed and ``GENERATOR_VERSION`` (what ``generate`` compares to skip work)."""
    payload = json.dumps(
        {"spec": asdict(spec), "seed": int(seed), "version": GENERATOR_VERSION}, sort_keys=True
    )
    return hashlib.sha256(payload.encode()).hexdigest()
