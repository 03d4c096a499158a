"""Frame-accurate, lazily decoded video frames (PyAV) with a byte-bounded frame cache.

Design: one ``VideoReader`` per video keeps its container open and a forward decoding position.
A request for frame ``i``
  1. returns the cached frame if present;
  2. otherwise decodes forward from the current position when ``i`` is a little ahead of it, or
     seeks to the key frame before ``i`` (frame index recovered from each frame's ``pts``);
  3. keeps decoding after ``i`` for ``readahead`` more frames (within the window, stopping early at
     a frame that is already cached), storing every frame at the target size as uint8.
So a window read in order (evaluation, video export) is decoded exactly once, and random access
(training) costs one seek plus a short run per miss. With ``readahead`` = the window length every
camera's window is decoded once and then served from memory, which is the right choice whenever
``FrameCache.max_bytes`` holds all cameras' windows (the N3V loader picks this automatically).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from moegs.data._io import resize_uint8

# a miss at most this many frames ahead of the decoder position is served by decoding forward
_FORWARD_GAP = 48


class FrameCache:
    """LRU of uint8 frames ``[H, W, 3]`` keyed by ``(video, index)``, bounded in bytes."""

    def __init__(self, max_bytes: int = 2 << 30) -> None:
        self.max_bytes = int(max_bytes)
        self.nbytes = 0
        self._items: OrderedDict[tuple[str, int], np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple[str, int]) -> np.ndarray | None:
        with self._lock:
            arr = self._items.get(key)
            if arr is not None:
                self._items.move_to_end(key)
            return arr

    def __contains__(self, key: tuple[str, int]) -> bool:
        return key in self._items

    def put(self, key: tuple[str, int], arr: np.ndarray) -> None:
        if arr.nbytes > self.max_bytes:
            return
        with self._lock:
            if key in self._items:
                self.nbytes -= self._items.pop(key).nbytes
            self._items[key] = arr
            self.nbytes += arr.nbytes
            while self.nbytes > self.max_bytes:
                _, old = self._items.popitem(last=False)
                self.nbytes -= old.nbytes

    def __len__(self) -> int:
        return len(self._items)

    def __getstate__(self) -> dict:  # pickled empty (DataLoader workers): frames are re-decoded there
        return {"max_bytes": self.max_bytes}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["max_bytes"])


class VideoReader:
    """Frames of one video file at ``size = (width, height)`` (native size when ``None``).

    Attributes (probed from the header when constructed; a corrupt file raises ``ValueError``):
        width, height: native frame size; num_frames: frames in the stream; fps: frame rate.
    """

    def __init__(
        self,
        path: Path,
        cache: FrameCache | None = None,
        size: tuple[int, int] | None = None,
        resample: str = "bicubic",
        readahead: int = 0,
        stop: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.cache = cache if cache is not None else FrameCache()
        self.resample = resample
        self.readahead = int(readahead)
        self._lock = threading.Lock()
        self._container = None
        self._decoder = None
        self._next = -1  # index of the next frame the open decoder will yield
        if not self.path.is_file():
            raise FileNotFoundError(f"video: expected file {self.path} but it does not exist")
        try:
            with av.open(str(self.path)) as container:
                if not container.streams.video:
                    raise ValueError(f"video {self.path} has no video stream")
                stream = container.streams.video[0]
                self.width = int(stream.codec_context.width)
                self.height = int(stream.codec_context.height)
                rate = stream.average_rate or stream.guessed_rate or stream.base_rate
                if not rate or self.width <= 0 or self.height <= 0:
                    raise ValueError(f"video {self.path}: no frame rate or frame size in the stream header")
                self.fps = Fraction(rate)
                self._time_base = Fraction(stream.time_base)
                self._start = int(stream.start_time or 0)
                frames = int(stream.frames or 0)
                if frames <= 0 and stream.duration:
                    frames = int(round(float(stream.duration * self._time_base * self.fps)))
                self.num_frames = frames
        except av.error.FFmpegError as err:
            raise ValueError(f"cannot open video {self.path} (corrupt or unsupported): {err}") from err
        if self.num_frames <= 0:
            raise ValueError(f"video {self.path}: the stream reports no frames (corrupt or empty file?)")
        self.size = size or (self.width, self.height)
        self.stop = self.num_frames if stop is None else min(int(stop), self.num_frames)

    # -- public ----------------------------------------------------------------------------------
    def frame(self, index: int) -> np.ndarray:
        """Frame ``index`` as uint8 ``[H, W, 3]`` at ``self.size``."""
        if not 0 <= index < self.num_frames:
            raise IndexError(f"video {self.path}: frame {index} outside 0..{self.num_frames - 1}")
        key = (str(self.path), index)
        hit = self.cache.get(key)
        if hit is not None:
            return hit
        with self._lock:
            hit = self.cache.get(key)
            if hit is None:
                hit = self._decode(index)
        return hit

    def __getstate__(self) -> dict:  # open decoders and locks stay in the process that made them
        state = self.__dict__.copy()
        state.update(_container=None, _decoder=None, _next=-1, _lock=None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container, self._decoder, self._next = None, None, -1

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    # -- decoding -------------------------------------------------------------------------------
    def _index_of(self, frame: av.VideoFrame, fallback: int) -> int:
        if frame.pts is None:
            return fallback
        return int(round(float((frame.pts - self._start) * self._time_base * self.fps)))

    def _seek(self, index: int) -> None:
        try:
            if self._container is None:
                self._container = av.open(str(self.path))
            stream = self._container.streams.video[0]
            target = self._start + int(index / self.fps / self._time_base)
            self._container.seek(target, stream=stream, backward=True, any_frame=False)
            self._decoder = self._container.decode(stream)
        except av.error.FFmpegError as err:
            self.close()
            raise ValueError(f"cannot seek in video {self.path} (corrupt?): {err}") from err
        self._next = -1  # unknown until the first decoded frame

    def _decode(self, index: int) -> np.ndarray:
        ahead = self._decoder is not None and 0 <= self._next <= index <= self._next + _FORWARD_GAP
        if not ahead:
            self._seek(index)
        last = min(self.stop, self.num_frames) - 1
        limit = max(index, min(index + self.readahead, last))
        result = None
        for attempt in range(2):
            try:
                result = self._run(index, limit)
            except av.error.FFmpegError as err:
                self.close()
                raise ValueError(f"cannot decode video {self.path} (corrupt?): {err}") from err
            if result is not None:
                return result
            if attempt == 0:  # overshot (seek landed after the frame): restart from the beginning
                self._seek(0)
        raise ValueError(f"video {self.path}: frame {index} not found while decoding (truncated file?)")

    def _run(self, index: int, limit: int) -> np.ndarray | None:
        result = None
        expected = self._next
        for frame in self._decoder:
            i = self._index_of(frame, expected if expected >= 0 else 0)
            expected = i + 1
            self._next = i + 1
            if i < index:
                continue
            if i > index and result is None:
                return None
            if (frame.width, frame.height) != (self.width, self.height):
                raise ValueError(
                    f"video {self.path}: frame {i} is {frame.width}x{frame.height} but the stream "
                    f"header says {self.width}x{self.height}"
                )
            key = (str(self.path), i)
            if i > index and key in self.cache:
                break
            arr = resize_uint8(frame.to_ndarray(format="rgb24"), self.size, self.resample)
            self.cache.put(key, arr)
            if i == index:
                result = arr
            if i >= limit:
                break
        else:
            self.close()
        return result
