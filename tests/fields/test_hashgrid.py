"""Grid4D hash encoding in pure torch: level geometry, dense/hashed indices, smoothstep, range, gradients."""

import math

import pytest
import torch

from moegs.fields import DecomposedHashGrid4D, HashGrid, smoothstep


def _grid(**kw):
    # base 4, desired 16, 3 levels -> growth 2; scales 3, 7, 15; resolutions 4, 8, 16; table 2^6 = 64
    args = dict(
        input_dim=3, num_levels=3, level_dim=1, base_resolution=4, desired_resolution=16, log2_hashmap_size=6
    )
    args.update(kw)
    return HashGrid(**args)


def test_smoothstep_values():
    f = torch.tensor([0.0, 0.25, 0.5, 1.0])
    assert smoothstep(f).tolist() == pytest.approx([0.0, 0.15625, 0.5, 1.0])


def test_level_geometry():
    g = _grid()
    assert g.scales[:, 0].tolist() == pytest.approx([3.0, 7.0, 15.0])
    assert g.resolutions[:, 0].tolist() == [4, 8, 16]
    assert g.sizes.tolist() == [64, 64, 64]  # 4^3 = 64 fits; 8^3, 16^3 are capped
    assert g.dense == (True, False, False)
    assert g.offsets.tolist() == [0, 64, 128, 192]


def test_dense_and_hashed_indices_hand_computed():
    g = _grid()
    cell = torch.tensor([[[1, 2, 3]] * 3])  # [N=1, L=3, D=3]
    # level 0 dense: 1 + 2 * 4 + 3 * 16 = 57
    # levels 1, 2 hashed: (1 * 1) ^ (2 * 2654435761 mod 2^32 = 1013904226) ^ (3 * 805459861 = 2416379583)
    #   = 2892625372; mod 64 = 28
    assert g.level_index(cell).tolist() == [[57, 28, 28]]


def test_per_dimension_resolutions_like_grid4d_dnerf():
    g = HashGrid(3, 32, 2, base_resolution=(8, 8, 8), desired_resolution=(32, 32, 16), log2_hashmap_size=19)
    assert g.resolutions[0].tolist() == [8, 8, 8]
    # the kernel computes the finest scale in float32: 31.0000229 on x and y, so 33 x 33 x 16 vertices
    # exceed the 32 x 32 x 16 rows the Python side allocated and the level is hashed (hashencoder.cu:157)
    assert g.resolutions[-1].tolist() == [33, 33, 16]
    assert g.dense == (True,) * 31 + (False,)
    assert g.sizes[-1] == 32 * 32 * 16 and g.embeddings.numel() == 322426
    canonical = HashGrid(3, 16, 2, 16, 2048, 19)
    assert canonical.dense.count(False) == 11  # spec: 11 of 16 levels hashed, ~12.2M parameters
    assert canonical.embeddings.numel() == 12196216


def test_init_range():
    g = HashGrid(3, 4, 2, 4, 16, 10)
    assert float(g.embeddings.detach().abs().max()) <= 1e-4


def _single_level_with_row_values():
    g = _grid(num_levels=1)  # dense, res 4, scale 3
    with torch.no_grad():
        g.embeddings.copy_(torch.arange(64.0).view(64, 1))
    return g


def test_lookup_at_a_vertex_and_between_vertices():
    g = _single_level_with_row_values()
    u = torch.tensor(
        [
            [1 / 3, 2 / 3, 1.0],  # vertex (1, 2, 3): row 57
            [1.5 / 3, 2 / 3, 1.0],  # halfway (1,2,3)-(2,2,3): smoothstep(0.5) = 0.5 -> (57 + 58) / 2
            [1.25 / 3, 2 / 3, 1.0],  # f = 0.25: 0.84375 * 57 + 0.15625 * 58
            [0.0, 0.0, 0.0],  # vertex (0, 0, 0): row 0
        ],
        dtype=torch.float32,
    )
    assert g(u)[:, 0].tolist() == pytest.approx([57.0, 57.5, 57.15625, 0.0], abs=1e-4)


def test_out_of_range_is_zero_without_gradient():
    g = _grid()
    with torch.no_grad():
        g.embeddings.fill_(1.0)
    u = torch.tensor(
        [[0.5, 0.5, 0.5], [1.01, 0.5, 0.5], [0.5, -1e-3, 0.5], [1.0, 1.0, 0.0]], requires_grad=True
    )
    out = g(u)
    assert out[1].abs().sum() == 0 and out[2].abs().sum() == 0
    assert out[0].tolist() == pytest.approx([1.0] * 3) and out[3].tolist() == pytest.approx([1.0] * 3)
    g.embeddings.grad = None
    g(u[1:3]).sum().backward()
    assert float(g.embeddings.grad.abs().sum()) == 0.0


def test_gradient_flows_to_the_corner_rows():
    g = _grid()
    u = torch.tensor([[0.3, 0.6, 0.9]])
    g(u).sum().backward()
    grad = g.embeddings.grad[:, 0]
    for level in range(3):
        block = grad[g.offsets[level] : g.offsets[level + 1]]
        assert float(block.sum()) == pytest.approx(1.0, abs=1e-6)  # weights of the 8 corners sum to 1
        assert int((block != 0).sum()) <= 8


def test_output_is_level_major():
    g = HashGrid(2, 3, 2, 2, 8, 8)
    with torch.no_grad():
        for level in range(3):
            rows = slice(g.offsets[level], g.offsets[level + 1])
            g.embeddings[rows] = torch.tensor([10.0 * level, 10.0 * level + 1])
    assert g(torch.tensor([[0.2, 0.7]]))[0].tolist() == pytest.approx([0, 1, 10, 11, 20, 21])


def test_decomposed_4d_mapping_and_block_order():
    enc = DecomposedHashGrid4D(
        bound=2.0,
        spatial_levels=2,
        spatial_base=4,
        spatial_desired=8,
        spatial_log2_size=10,
        temporal_levels=2,
        temporal_base=(4, 4, 4),
        temporal_desired=(8, 8, 4),
        temporal_log2_size=10,
    )
    assert enc.time_coordinate(torch.tensor([0.0, 1.0])).tolist() == pytest.approx([-1.8, 1.8])
    assert enc._unit(enc.time_coordinate(torch.tensor([0.0, 1.0]))).tolist() == pytest.approx([0.05, 0.95])
    assert enc.spatial_dim == 4 and enc.temporal_dim == 12
    xyz = torch.tensor([[0.3, -0.4, 1.1]])
    xyzt = torch.cat([xyz, enc.time_coordinate(torch.tensor([[0.25]]))], -1)
    h_t = enc.encode_temporal(xyzt)
    for k, (a, b) in enumerate(enc.PAIRS):
        expected = enc.temporal[k](enc._unit(xyzt[:, [a, b, 3]]))
        assert torch.equal(h_t[:, 4 * k : 4 * k + 4], expected)
    # the xyt grid ignores z; the yzt grid ignores x
    moved = xyzt.clone()
    moved[0, 2] += 0.3
    assert torch.equal(enc.encode_temporal(moved)[:, :4], h_t[:, :4])
    assert enc.encode_spatial(torch.tensor([[2.5, 0.0, 0.0]])).abs().sum() == 0  # outside the bound


def test_shape_errors():
    with pytest.raises(ValueError, match=r"expects u \[N, 3\]"):
        _grid()(torch.zeros(4, 2))
    with pytest.raises(ValueError, match="base_resolution"):
        HashGrid(3, 2, 2, base_resolution=(4, 4))


def test_dense_levels_of_a_non_cubic_grid_give_every_vertex_its_own_row():
    """Row-major strides ``(1, r_x, r_x r_y)`` from each level's own per-axis resolutions: on an (x, y, t)
    grid of unequal sides no two vertices of a dense level share a row."""
    g = HashGrid(3, 2, 2, base_resolution=(4, 6, 3), desired_resolution=(8, 12, 5), log2_hashmap_size=16)
    assert all(g.dense)
    for level in range(2):
        r = g.resolutions[level].tolist()
        assert len(set(r)) == 3  # unequal sides
        assert g.strides[level].tolist() == [1, r[0], r[0] * r[1]]
        vertices = torch.cartesian_prod(*(torch.arange(n) for n in r))  # every vertex (x, y, t)
        rows = (vertices * g.strides[level]).sum(-1)
        assert len(set(rows.tolist())) == math.prod(r) == int(g.sizes[level])
