"""Shared 3DGS per-Gaussian parameters: initialisation, activation, SH-degree schedule."""

import math

import pytest
import torch

from moegs.data.points import initial_scales
from moegs.data.scene import PointCloud
from moegs.experts.gaussian_params import (
    activate,
    active_sh_degree,
    init_splats,
    num_sh_bases,
)
from moegs.render.projection import SH_C0, rgb_to_sh0, sh0_to_rgb


def _cloud(n=50):
    g = torch.Generator().manual_seed(0)
    return PointCloud(torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g))


def test_init_follows_3dgs():
    cloud = _cloud()
    splats = init_splats(cloud)
    assert {k: tuple(v.shape) for k, v in splats.items()} == {
        "means": (50, 3),
        "scales": (50, 3),
        "quats": (50, 4),
        "opacities": (50,),
        "sh0": (50, 1, 3),
        "shN": (50, 15, 3),
    }
    torch.testing.assert_close(splats["means"], cloud.xyz)
    torch.testing.assert_close(splats["scales"], initial_scales(cloud.xyz))  # log sqrt(mean 3-NN dist²)
    assert (splats["quats"] == torch.tensor([1.0, 0.0, 0.0, 0.0])).all()
    torch.testing.assert_close(torch.sigmoid(splats["opacities"]), torch.full((50,), 0.1))
    torch.testing.assert_close(splats["sh0"][:, 0], (cloud.rgb - 0.5) / 0.28209479177387814)
    assert (splats["shN"] == 0).all() and all(p.requires_grad for p in splats.values())


def test_init_options_and_extras():
    cloud = _cloud()
    splats = init_splats(
        cloud, sh_degree=1, init_opacity=0.5, init_scale=0.1, extra={"embed": torch.zeros(50, 8)}
    )
    assert splats["shN"].shape == (50, 3, 3) and splats["embed"].shape == (50, 8)
    torch.testing.assert_close(splats["scales"], initial_scales(cloud.xyz) + math.log(0.1))
    torch.testing.assert_close(torch.sigmoid(splats["opacities"]), torch.full((50,), 0.5))
    with pytest.raises(ValueError, match="extra parameter 'means' collides"):
        init_splats(cloud, extra={"means": torch.zeros(50, 3)})
    with pytest.raises(ValueError, match="must have leading dim 50"):
        init_splats(cloud, extra={"embed": torch.zeros(49, 8)})
    with pytest.raises(ValueError, match=r"init_opacity must be in \(0, 1\)"):
        init_splats(cloud, init_opacity=1.0)


def test_activate_and_overrides():
    splats = init_splats(_cloud())
    with torch.no_grad():
        splats["quats"].mul_(3.0)
    frame = activate(splats, active_sh_degree=2)
    torch.testing.assert_close(frame.quats.norm(dim=-1), torch.ones(50))
    torch.testing.assert_close(frame.scales, torch.exp(splats["scales"]))
    assert frame.sh.shape == (50, 9, 3) and frame.sh_degree == 2
    moved = activate(splats, 0, means=splats["means"] + 1.0)
    torch.testing.assert_close(moved.means, splats["means"] + 1.0)
    assert moved.sh.shape == (50, 1, 3)
    with pytest.raises(ValueError, match="unknown overrides"):
        activate(splats, 0, colour=splats["means"])
    with pytest.raises(ValueError, match=r"active_sh_degree must be in 0..3"):
        activate(splats, 4)


def test_sh_schedule_and_helpers():
    # 3DGS: oneupSHdegree when iteration % 1000 == 0, before rendering that iteration
    assert [active_sh_degree(s, 3, 1000) for s in (1, 999, 1000, 2500, 3000, 30_000)] == [0, 0, 1, 2, 3, 3]
    assert active_sh_degree(5000, 1, 1000) == 1 and active_sh_degree(100, 3, 35) == 2
    assert num_sh_bases(3) == 16 and SH_C0 == pytest.approx(0.28209479)
    rgb = torch.rand(4, 3)
    torch.testing.assert_close(sh0_to_rgb(rgb_to_sh0(rgb)), rgb)
