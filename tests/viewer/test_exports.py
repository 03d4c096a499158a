"""``moegs export --format ply|splat --times``: one file per time, the index, the PLY round trip and the
``.splat`` byte layout."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from moegs.cli import EXPORT_FORMATS, main
from moegs.exports import FORMATS, SPLAT_DTYPE, read_splat, splat_bytes
from moegs.gaussians import GaussianFrame
from moegs.io import read_ply
from moegs.render.projection import rgb_to_sh0, sh0_to_rgb


def _frame(n=50, sh=True):
    g = torch.Generator().manual_seed(0)
    colors = torch.rand(n, 3, generator=g)
    return GaussianFrame(
        means=torch.randn(n, 3, generator=g),
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        scales=torch.rand(n, 3, generator=g) * 0.1 + 0.001,
        opacities=torch.rand(n, generator=g),
        **({"sh": rgb_to_sh0(colors)[:, None, :]} if sh else {"colors": colors}),
    )


def test_the_cli_names_the_formats():
    assert EXPORT_FORMATS == FORMATS


@pytest.mark.parametrize("sh", [True, False])
def test_splat_layout_decodes_within_quantisation(sh):
    frame = _frame(sh=sh)
    raw = splat_bytes(frame)
    assert SPLAT_DTYPE.itemsize == 32 and len(raw) == 32 * len(frame)
    records = np.frombuffer(raw, dtype=SPLAT_DTYPE)
    # byte offsets of antimatter15/splat: position 0, scale 12, rgba 24, rotation 28
    assert [SPLAT_DTYPE.fields[k][1] for k in ("position", "scale", "rgba", "rotation")] == [0, 12, 24, 28]
    position = np.frombuffer(raw, "<f4").reshape(-1, 8)[:, :3]
    np.testing.assert_array_equal(position, records["position"])

    # sorted by volume x opacity, largest first; match each record to its Gaussian by position
    weight = frame.scales.prod(1) * frame.opacities
    order = torch.argsort(-weight).numpy()
    decoded = _read(raw)
    np.testing.assert_array_equal(decoded["position"], frame.means[order].numpy())
    np.testing.assert_allclose(decoded["scale"], frame.scales[order].numpy(), rtol=1e-6)
    rgb = frame.colors if frame.colors is not None else sh0_to_rgb(frame.sh[:, 0])
    np.testing.assert_allclose(decoded["rgba"][:, :3], rgb[order].clamp(0, 1).numpy(), atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(decoded["rgba"][:, 3], frame.opacities[order].numpy(), atol=0.5 / 255 + 1e-6)
    quats = frame.quats[order].numpy()
    np.testing.assert_allclose(decoded["rotation"], quats, atol=1 / 128 + 1e-6)  # 1.0 clips to 255


def _read(raw: bytes) -> dict[str, np.ndarray]:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "g.splat"
        path.write_bytes(raw)
        return read_splat(path)


@pytest.mark.slow
def test_export_times_round_trip(tiny_route, tmp_path, capsys):
    """Per-time PLY files read back into moegs give the expert's Gaussians at each time, which move; the
    .splat files hold 32 bytes per Gaussian; index.json lists times and files; --time writes one file."""
    from moegs.cli import _load_run

    run = tiny_route / "deformable"
    out = tmp_path / "ply"
    assert main(["export", str(run), "--times", "0,0.5,1", "--out", str(out)]) == 0
    assert (
        f"Gaussians at 3 times (t=0.000 .. 1.000) -> {out}: 3 .ply files, index.json"
        in capsys.readouterr().out
    )
    index = json.loads((out / "index.json").read_text())
    assert index["format"] == "ply" and index["expert"] == "deformable"
    assert [f["time"] for f in index["frames"]] == [0.0, 0.5, 1.0]
    _, _, scene, expert = _load_run(str(run))
    moved = []
    with torch.no_grad():
        for entry in index["frames"]:
            frame = expert.frame(entry["time"])
            back = read_ply(out / entry["file"])
            assert len(back) == entry["num_gaussians"] == len(frame)
            torch.testing.assert_close(back.means, frame.means, rtol=0, atol=0)
            torch.testing.assert_close(back.quats, torch.nn.functional.normalize(frame.quats, dim=-1))
            # Deformable 3DGS adds scale offsets after exp: a scale may be negative; its square counts
            torch.testing.assert_close(back.scales, frame.scales.abs(), rtol=1e-5, atol=1e-7)
            torch.testing.assert_close(back.opacities, frame.opacities, rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(back.sh, frame.sh, rtol=0, atol=0)
            moved.append(back.means)
    assert not torch.equal(moved[0], moved[2])  # a deforming expert: the Gaussians move with time

    assert main(["export", str(run), "--times", "all", "--format", "splat"]) == 0
    index = json.loads((run / "export_splat" / "index.json").read_text())
    assert [f["time"] for f in index["frames"]] == pytest.approx(scene.times.tolist(), abs=1e-6)
    for entry in index["frames"]:
        assert (run / "export_splat" / entry["file"]).stat().st_size == 32 * entry["num_gaussians"]

    assert (
        main(["export", str(run), "--time", "0.5", "--format", "splat", "--out", str(tmp_path / "g.splat")])
        == 0
    )
    with torch.no_grad():
        assert (tmp_path / "g.splat").read_bytes() == splat_bytes(expert.frame(0.5))
    assert main(["export", str(run), "--time", "0.5"]) == 0
    assert (run / "point_cloud_t0.500.ply").is_file()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--times", "0,2"], "--times expects 'all' or comma-separated times in [0, 1], got '2'"),
        (["--times", "x"], "--times expects 'all' or comma-separated times in [0, 1], got 'x'"),
    ],
)
def test_bad_times_fail_in_one_line(tmp_path, capsys, argv, message):
    assert main(["export", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err
    assert err == f"moegs export: {message}\n"


def test_time_and_times_exclude_each_other(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["export", str(tmp_path), "--time", "0.5", "--times", "all"])
    assert "not allowed with argument" in capsys.readouterr().err
