"""4DGaussians HexPlane: sampling rule, plane order, product/concat, AABB map, init and regularisers."""

import pytest
import torch

from moegs.fields import HexPlane, plane_smoothness, sample_plane
from moegs.fields.hexplane import COMBINATIONS, SPATIAL_PLANES, TIME_PLANES, normalize_aabb


def _plane(h, w):
    return torch.arange(h * w, dtype=torch.float64).view(1, 1, h, w)


def test_sample_plane_nodes_midpoints_and_border():
    plane = _plane(3, 4)  # value = 4 * row + col
    coords = torch.tensor(
        [
            [-1.0, -1.0],  # node (row 0, col 0)
            [1.0, 1.0],  # node (2, 3)
            [-1.0 + 2.0 / 3.0, 0.0],  # node (1, 1): align_corners puts col k at -1 + 2k / 3
            [-1.0 + 1.0 / 3.0, -0.5],  # midpoint of cols 0,1 and rows 0,1
            [3.0, 0.0],  # beyond the right edge: border padding -> col 3, row 1
        ],
        dtype=torch.float64,
    )
    got = sample_plane(plane, coords)[:, 0].tolist()
    assert got == pytest.approx([0.0, 11.0, 5.0, (0 + 1 + 4 + 5) / 4, 7.0])


def test_plane_order_and_shapes():
    assert COMBINATIONS == ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))  # xy xz xt yz yt zt
    assert SPATIAL_PLANES == (0, 1, 3) and TIME_PLANES == (2, 4, 5)
    field = HexPlane(resolution=(4, 5, 6, 7), feature_dim=3, multires=(1, 2))
    shapes = [tuple(p.shape) for p in field.scales[0]]
    assert shapes == [(1, 3, 5, 4), (1, 3, 6, 4), (1, 3, 7, 4), (1, 3, 6, 5), (1, 3, 7, 5), (1, 3, 7, 6)]
    assert tuple(field.scales[1][0].shape) == (1, 3, 10, 8)  # spatial x2, time unchanged
    assert tuple(field.scales[1][2].shape) == (1, 3, 7, 8)
    assert field.out_dim == 6


def test_init_rules():
    field = HexPlane(resolution=(8, 8, 8, 5), feature_dim=4)
    for p in field.planes("space"):
        assert 0.1 <= float(p.detach().min()) and float(p.detach().max()) <= 0.5
    for p in field.planes("time"):
        assert torch.equal(p.detach(), torch.ones_like(p))


def test_aabb_map_is_the_original_mirrored_one():
    aabb = torch.tensor([[2.0, 2.0, 2.0], [-2.0, 0.0, -2.0]])  # original stores [max, min]
    pts = torch.tensor([[2.0, 2.0, 2.0], [-2.0, 0.0, -2.0], [0.0, 1.0, 1.0]])
    assert normalize_aabb(pts, aabb).tolist() == [[-1.0] * 3, [1.0] * 3, [0.0, 0.0, -0.5]]


def test_product_of_planes_and_concat_over_scales():
    field = HexPlane(
        resolution=(3, 3, 3, 3), feature_dim=1, multires=(1, 2), aabb_min=(-1.0,) * 3, aabb_max=(1.0,) * 3
    )
    with torch.no_grad():
        for k, p in enumerate(field.scales[0]):
            p.fill_(k + 1.0)  # constant planes: product = 6!
        for p in field.scales[1]:
            p.fill_(1.0)
        # scale-1 xy plane varies along x (its W axis): column j holds j
        xy = field.scales[1][0]
        xy.copy_(torch.arange(xy.shape[-1], dtype=xy.dtype).expand_as(xy))
    xyz = torch.tensor([[1.0, 0.3, -0.2], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    out = field(xyz, torch.full((3, 1), 0.5))
    assert out[:, 0].tolist() == pytest.approx([720.0] * 3)
    # x = max -> normalised -1 -> column 0; x = min -> +1 -> last column (5); x = 0 -> middle (2.5)
    assert out[:, 1].tolist() == pytest.approx([0.0, 5.0, 2.5])


def test_time_is_used_raw():
    field = HexPlane(resolution=(2, 2, 2, 3), feature_dim=1, multires=(1,))
    with torch.no_grad():
        for p in field.planes():
            p.fill_(1.0)
        xt = field.scales[0][2]  # [1, 1, T=3, X=2]: row k holds 10 k
        xt.copy_(10.0 * torch.arange(3.0).view(1, 1, 3, 1).expand_as(xt))
    out = field(torch.zeros(3, 3), torch.tensor([[0.0], [0.5], [1.0]]))
    assert out[:, 0].tolist() == pytest.approx([10.0, 15.0, 20.0])  # t=0 is the middle row


def test_plane_smoothness_hand_values():
    quad = (torch.arange(5.0) ** 2).view(1, 1, 5, 1).expand(1, 2, 5, 3)  # second difference = 2
    assert float(plane_smoothness(quad)) == pytest.approx(4.0)
    along_w = torch.arange(5.0).view(1, 1, 1, 5).expand(1, 1, 4, 5) ** 2  # varies along W only
    assert float(plane_smoothness(along_w)) == 0.0


def test_regularisers_sum_over_planes_and_scales():
    field = HexPlane(resolution=(4, 4, 4, 4), feature_dim=1, multires=(1, 2))

    def rows(p):  # row r holds r^2: second difference 2 along the height axis
        return (torch.arange(float(p.shape[2])) ** 2).view(1, 1, -1, 1).expand_as(p)

    with torch.no_grad():
        for p in field.planes("space"):  # 4 or 8 rows
            p.copy_(rows(p))
        for p in field.planes("time"):  # 4 rows (t is not multiplied): 0, 0.5, 2, 4.5
            p.copy_(0.5 * rows(p))
    with torch.no_grad():
        ls, lt, l1t = field.space_smoothness(), field.time_smoothness(), field.time_l1()
    assert float(ls) == pytest.approx(6 * 4.0)
    assert float(lt) == pytest.approx(6 * 1.0)
    assert float(l1t) == pytest.approx(6 * (1 + 0.5 + 1 + 3.5) / 4)  # mean |1 - p| = 1.5


def test_gradients_reach_every_plane():
    field = HexPlane(resolution=(4, 4, 4, 4), feature_dim=2)
    field(torch.rand(10, 3) * 2 - 1, torch.rand(10, 1)).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in field.planes())


def test_shape_errors():
    field = HexPlane(resolution=(4, 4, 4, 4), feature_dim=2)
    with pytest.raises(ValueError, match=r"t must have shape \[5, 1\]"):
        field(torch.zeros(5, 3), torch.zeros(5))
    with pytest.raises(ValueError, match="min < max"):
        field.set_aabb(torch.ones(3), torch.zeros(3))
