"""mp4 files through PyAV (libx264): the one video stack of moegs (stand-in videos, rendered test views)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np


def codec_settings(codec: str) -> tuple[str, str, dict[str, str]]:
    """``(codec, pixel format, options)`` of ``lossless`` (bit-exact RGB), ``yuv444`` (qp 0, any size) or
    ``yuv420`` (crf 18, like real N3V videos; even sizes)."""
    if codec == "lossless":
        if "libx264rgb" in av.codecs_available:
            return "libx264rgb", "rgb24", {"qp": "0", "preset": "veryfast"}
        return "libx264", "yuv444p", {"qp": "0", "preset": "veryfast"}
    if codec == "yuv444":
        return "libx264", "yuv444p", {"qp": "0", "preset": "veryfast"}
    if codec == "yuv420":
        return "libx264", "yuv420p", {"crf": "18", "preset": "veryfast"}
    raise ValueError(f"unknown codec {codec!r}; valid: lossless, yuv444, yuv420")


class VideoWriter:
    """mp4 writer (PyAV / libx264) taking uint8 ``[H, W, 3]`` RGB frames; frame i gets pts i at 1/fps."""

    def __init__(self, path: Path, width: int, height: int, fps: int, codec: str = "lossless") -> None:
        self.codec_name, self.pix_fmt, options = codec_settings(codec)
        self.container = av.open(str(path), mode="w")
        self.stream = self.container.add_stream(self.codec_name, rate=fps)
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = self.pix_fmt
        self.stream.options = options
        self.rate = Fraction(1, fps)
        self.count = 0

    def write(self, frame: np.ndarray) -> None:
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        vf.pts = self.count
        vf.time_base = self.rate
        self.count += 1
        for packet in self.stream.encode(vf):
            self.container.mux(packet)

    def close(self) -> None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def decode_video(path: Path) -> np.ndarray:
    """All frames of a video as uint8 ``[T, H, W, 3]`` (PyAV)."""
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


__all__ = ["VideoWriter", "codec_settings", "decode_video"]
