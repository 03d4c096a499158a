"""MLP blocks: layer widths, the DeformableGS skip, heads, Xavier init."""

import pytest
import torch
from torch import nn

from moegs.fields import Heads, SkipMLP, mlp, xavier_weights_


def test_mlp_layout():
    net = mlp([5, 8, 3], relu_first=True)
    kinds = [type(m).__name__ for m in net]
    assert kinds == ["ReLU", "Linear", "ReLU", "Linear"]
    assert [m.out_features for m in net if isinstance(m, nn.Linear)] == [8, 3]
    assert [type(m).__name__ for m in mlp([4, 4, 4], relu_last=True)] == ["Linear", "ReLU", "Linear", "ReLU"]


def test_skip_mlp_widths_like_deformable_gs():
    net = SkipMLP(in_dim=76, width=256, depth=8, skips=(4,))
    assert [layer.in_features for layer in net.layers] == [76, 256, 256, 256, 256, 256 + 76, 256, 256]
    assert net(torch.zeros(3, 76)).shape == (3, 256)


def test_skip_mlp_reinjects_the_input():
    torch.manual_seed(0)
    net = SkipMLP(in_dim=2, width=3, depth=3, skips=(1,))
    x = torch.randn(4, 2)
    h = torch.relu(net.layers[0](x))
    h = torch.relu(net.layers[1](h))
    h = torch.relu(net.layers[2](torch.cat([x, h], -1)))
    assert torch.allclose(net(x), h)


def test_skip_mlp_rejects_bad_skips():
    with pytest.raises(ValueError, match="skips"):
        SkipMLP(3, 8, depth=2, skips=(1,))


def test_heads_shapes_and_order():
    heads = Heads(16, {"dx": 3, "dr": 4, "ds": 3}, hidden=(16,), relu_first=True)
    out = heads(torch.randn(5, 16))
    assert list(out) == ["dx", "dr", "ds"]
    assert [v.shape[-1] for v in out.values()] == [3, 4, 3]


def test_xavier_weights_keeps_biases():
    torch.manual_seed(0)
    net = mlp([64, 64, 3])
    biases = [m.bias.clone() for m in net if isinstance(m, nn.Linear)]
    xavier_weights_(net)
    bound = (6 / (64 + 64)) ** 0.5
    assert net[0].weight.abs().max() <= bound
    linears = [m for m in net if isinstance(m, nn.Linear)]
    assert all(torch.equal(b, m.bias) for b, m in zip(biases, linears, strict=True))
