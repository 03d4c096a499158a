"""3DGS PLY export: standard property layout and values, and the read-back round trip."""

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from moegs.gaussians import GaussianFrame
from moegs.io import export_ply, read_ply
from moegs.render.projection import rgb_to_sh0


def _frame(n=6, degree=3):
    g = torch.Generator().manual_seed(0)
    return GaussianFrame(
        means=torch.randn(n, 3, generator=g),
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        scales=torch.rand(n, 3, generator=g) + 0.01,
        opacities=torch.rand(n, generator=g) * 0.98 + 0.01,
        sh=torch.randn(n, (degree + 1) ** 2, 3, generator=g),
    )


def test_layout_and_raw_values(tmp_path):
    frame = _frame()
    path = export_ply(frame, tmp_path / "point_cloud.ply")
    vertex = PlyData.read(str(path))["vertex"]
    names = [p.name for p in vertex.properties]
    expected = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity", "scale_0", "scale_1", "scale_2"]
        + [f"rot_{i}" for i in range(4)]
    )
    assert names == expected
    assert all(p.val_dtype in ("f4", "float32") for p in vertex.properties)

    def col(name):
        return torch.from_numpy(np.asarray(vertex[name]))

    torch.testing.assert_close(col("y"), frame.means[:, 1])
    assert (col("nx") == 0).all()
    torch.testing.assert_close(col("opacity"), torch.logit(frame.opacities))
    torch.testing.assert_close(col("scale_2"), torch.log(frame.scales[:, 2]))
    torch.testing.assert_close(col("rot_0"), frame.quats[:, 0])  # w first
    torch.testing.assert_close(col("f_dc_1"), frame.sh[:, 0, 1])
    # channel-major f_rest: all 15 bands of R, then G, then B
    torch.testing.assert_close(col("f_rest_0"), frame.sh[:, 1, 0])
    torch.testing.assert_close(col("f_rest_14"), frame.sh[:, 15, 0])
    torch.testing.assert_close(col("f_rest_15"), frame.sh[:, 1, 1])


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip(tmp_path, degree):
    frame = _frame(degree=degree)
    back = read_ply(export_ply(frame, tmp_path / "g.ply"))
    for name in ("means", "quats", "scales", "opacities", "sh"):
        torch.testing.assert_close(getattr(back, name), getattr(frame, name), rtol=1e-5, atol=1e-6)


def test_raw_quaternions_of_a_3dgs_file_are_normalised(tmp_path):
    """3DGS writes its raw ``_rotation``; the activated frame has unit quaternions."""
    path = export_ply(_frame(), tmp_path / "g.ply")
    data = PlyData.read(str(path))["vertex"].data
    for i in range(4):
        data[f"rot_{i}"] *= 3.0
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "raw.ply"))
    back = read_ply(tmp_path / "raw.ply")
    torch.testing.assert_close(back.quats, read_ply(path).quats)
    torch.testing.assert_close(back.quats.norm(dim=-1), torch.ones(len(back)))


def test_rgb_frame_becomes_dc_only(tmp_path):
    frame = _frame()
    rgb = frame.with_colors(torch.rand(len(frame), 3))
    back = read_ply(export_ply(rgb, tmp_path / "rgb.ply"))
    assert back.sh.shape == (len(frame), 1, 3)
    torch.testing.assert_close(back.sh[:, 0], rgb_to_sh0(rgb.colors))


def test_errors(tmp_path):
    with pytest.raises(ValueError, match="writes RGB; the frame has 5 colour channels"):
        export_ply(_frame().with_colors(torch.rand(6, 5)), tmp_path / "x.ply")
    arr = PlyData.read(str(export_ply(_frame(), tmp_path / "ok.ply")))["vertex"].data
    names = [n for n in arr.dtype.names if n != "opacity"]
    stripped = np.empty(len(arr), dtype=[(n, "f4") for n in names])
    for n in names:
        stripped[n] = arr[n]
    PlyData([PlyElement.describe(stripped, "vertex")]).write(str(tmp_path / "bad.ply"))
    with pytest.raises(ValueError, match="missing property 'opacity'"):
        read_ply(tmp_path / "bad.ply")
