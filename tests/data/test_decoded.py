"""Decoded images kept on disk between processes (``moegs.data.decoded``) and in memory (``ImageCache``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from moegs import paths
from moegs.data import _io, decoded
from moegs.data.scene import ImageCache, PointCloud

WHITE = torch.ones(3)


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("MOEGS_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("MOEGS_DECODED_CACHE", raising=False)
    return tmp_path / "cache" / "decoded"


@pytest.fixture
def rgba(tmp_path) -> Path:
    rng = np.random.default_rng(0)
    path = tmp_path / "r_000.png"
    Image.fromarray(rng.integers(0, 256, (64, 48, 4), dtype=np.uint8), "RGBA").save(path)
    return path


def _entries(cache: Path) -> list[Path]:
    return sorted(cache.rglob("*.npz")) if cache.exists() else []


def test_second_load_reads_the_stored_result_bit_for_bit(cache, rgba, monkeypatch):
    with monkeypatch.context() as m:
        m.setenv("MOEGS_DECODED_CACHE", "0")
        fresh = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert _entries(cache) == []
    first = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert len(_entries(cache)) == 1

    def no_decoding(path):
        raise AssertionError("decoded again")

    monkeypatch.setattr(_io, "read_image", no_decoding)
    second = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert second.shape == (32, 24, 3) and torch.equal(first, fresh) and torch.equal(second, fresh)


def test_every_argument_and_the_file_itself_are_in_the_key(cache, rgba):
    _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    _io.load_rgb(rgba, (48, 64), (24, 32), torch.zeros(3), "bicubic")
    _io.load_rgb(rgba, (48, 64), (12, 16), WHITE, "bicubic")
    _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "area")
    _io.load_alpha_mask(rgba, (48, 64), (24, 32), "bicubic")
    assert len(_entries(cache)) == 5
    stat = rgba.stat()
    os.utime(rgba, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # the file changed
    _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert len(_entries(cache)) == 6


def _store(entry: Path, value: np.ndarray, digest_of: np.ndarray | None = None) -> None:
    """An entry holding ``value`` with the digest of ``digest_of`` (default: of ``value`` itself)."""
    with open(entry, "wb") as f:
        np.savez(f, value=value, sha256=np.array(decoded._digest(value if digest_of is None else digest_of)))


def test_damaged_or_edited_entry_is_decoded_again_and_replaced(cache, rgba):
    good = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    (entry,) = _entries(cache)

    def reload() -> None:
        again = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
        torch.testing.assert_close(again, good, rtol=0, atol=0)

    entry.write_bytes(entry.read_bytes()[:100])  # truncated
    reload()
    _store(entry, np.zeros((3, 3), np.uint8))  # wrong shape
    reload()
    _store(entry, np.zeros((32, 24, 3), np.float32))  # wrong dtype (a float32 image of an older library)
    reload()
    edited = good.numpy().copy()
    edited[0, 0, 0] ^= 1
    _store(entry, edited, digest_of=good.numpy())  # one value changed after it was written
    reload()
    with np.load(entry) as z:
        assert np.array_equal(z["value"], good.numpy()) and str(z["sha256"]) == decoded._digest(good.numpy())


def test_rgba_ground_truth_is_the_truncated_8bit_composite_of_the_gs_loaders(rgba):
    """4DGaussians / DeformableGS / Grid4D composite D-NeRF's RGBA in float64 and cast ``arr * 255.0`` to
    ``np.byte`` (read back as RGB bytes): truncation, not rounding. The composite is then resized in
    8 bits."""
    arr = np.asarray(Image.open(rgba))
    for bg in (WHITE, torch.zeros(3), torch.tensor([0.2, 0.5, 0.9])):
        norm = arr / 255.0
        composite = norm[..., :3] * norm[..., 3:] + bg.double().numpy() * (1 - norm[..., 3:])
        with np.errstate(invalid="ignore"):  # numpy warns on the out-of-range int8 cast the loaders rely on
            theirs = np.array(composite * 255.0, dtype=np.byte).view(np.uint8)
        np.testing.assert_array_equal(_io.to_rgb8(arr, bg), theirs)
    rgb = arr[..., :3].copy()
    np.testing.assert_array_equal(_io.to_rgb8(rgb, WHITE), rgb)  # RGB passes through
    image = _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert image.dtype == torch.uint8 and image.shape == (32, 24, 3)
    resized = _io.resize_uint8(_io.to_rgb8(arr, WHITE), (24, 32), "bicubic")
    np.testing.assert_array_equal(image.numpy(), resized)


def test_large_images_and_missing_files_bypass_the_cache(cache, rgba, monkeypatch):
    monkeypatch.setattr(decoded, "MAX_PIXELS", 100)
    _io.load_rgb(rgba, (48, 64), (24, 32), WHITE, "bicubic")
    assert _entries(cache) == []
    with pytest.raises(FileNotFoundError, match="nope.png"):
        _io.load_rgb(rgba.with_name("nope.png"), (48, 64), (24, 32), WHITE, "bicubic")


def test_cache_root_is_never_the_install_tree(tmp_path, monkeypatch):
    monkeypatch.delenv("MOEGS_CACHE", raising=False)
    installed = tmp_path / "site-packages"
    installed.mkdir()
    monkeypatch.setattr(paths, "_REPO", installed)  # an installed copy: a folder without pyproject.toml
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert paths.cache_root() == tmp_path / "xdg" / "moegs"
    (installed / "pyproject.toml").write_text("")  # a source checkout keeps its cache beside the code
    assert paths.cache_root() == installed / ".cache"


def test_memory_cache_is_bounded_by_bytes_and_items():
    def image(value: float) -> torch.Tensor:
        return torch.full((10, 10, 3), float(value))  # 1200 bytes

    cache = ImageCache(max_bytes=3000)
    for k in range(3):
        cache.get(str(k), lambda k=k: image(k))
    assert len(cache) == 2 and cache.bytes == 2400  # "0" was evicted, least recently used
    assert float(cache.get("2", lambda: image(-1))[0, 0, 0]) == 2.0  # a hit does not load
    items = ImageCache(max_items=1)
    items.get("a", lambda: image(0))
    items.get("b", lambda: image(1))
    assert len(items) == 1 and items.bytes == 1200
    assert len(ImageCache(max_items=0).get("a", lambda: image(0))) == 10


def _cloud(seed: int) -> PointCloud:
    g = torch.Generator().manual_seed(seed)
    return PointCloud(torch.rand(50, 3, generator=g), torch.rand(50, 3, generator=g), f"made from {seed}")


def test_points_are_computed_once_per_sources_and_arguments(cache, rgba, tmp_path):
    calls = []

    def make(seed: int):
        def load():
            calls.append(seed)
            return _cloud(seed)

        return load

    first = decoded.cached_points([rgba], (0,), make(0))
    again = decoded.cached_points([rgba], (0,), make(0))
    assert calls == [0] and torch.equal(first.xyz, again.xyz) and torch.equal(first.rgb, again.rgb)
    assert again.source == "made from 0"
    decoded.cached_points([rgba], (1,), make(1))  # other arguments
    other = tmp_path / "other.png"
    other.write_bytes(rgba.read_bytes())
    decoded.cached_points([rgba, other], (0,), make(0))  # another source
    stat = rgba.stat()
    os.utime(rgba, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # the file changed
    decoded.cached_points([rgba], (0,), make(0))
    assert calls == [0, 1, 0, 0]


def test_damaged_points_entry_is_computed_again_and_failures_are_not_stored(cache, rgba):
    decoded.cached_points([rgba], (0,), lambda: _cloud(0))
    (entry,) = sorted(cache.rglob("*.npz"))
    entry.write_bytes(b"not a zip")
    assert torch.equal(decoded.cached_points([rgba], (0,), lambda: _cloud(0)).xyz, _cloud(0).xyz)

    def fails():
        raise ValueError("nothing triangulated")

    with pytest.raises(ValueError, match="nothing triangulated"):
        decoded.cached_points([rgba], (2,), fails)
    assert len(sorted(cache.rglob("*.npz"))) == 1
