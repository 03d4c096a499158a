"""NeRF positional encoding: values, order and widths (DeformableGS: 63 for xyz at L=10, 13 for t at L=6)."""

import math

import pytest
import torch

from moegs.fields import PositionalEncoding, positional_encoding


def test_values_and_order_hand_checked():
    x = torch.tensor([[0.5, -1.0]], dtype=torch.float64)
    got = positional_encoding(x, num_freqs=2)[0].tolist()
    s, c = math.sin, math.cos
    expected = [0.5, -1.0, s(0.5), s(-1.0), c(0.5), c(-1.0), s(1.0), s(-2.0), c(1.0), c(-2.0)]
    assert got == pytest.approx(expected, abs=1e-12)


def test_without_input_and_zero_frequencies():
    x = torch.tensor([[0.25]])
    assert positional_encoding(x, 0).tolist() == [[0.25]]
    got = positional_encoding(x, 1, include_input=False)[0].tolist()
    assert got == pytest.approx([math.sin(0.25), math.cos(0.25)])


@pytest.mark.parametrize(("dim", "freqs", "width"), [(3, 10, 63), (1, 6, 13), (1, 10, 21)])
def test_widths_match_deformable_gs(dim, freqs, width):
    enc = PositionalEncoding(dim, freqs)
    assert enc.out_dim == width
    assert enc(torch.zeros(7, 4, dim)).shape == (7, 4, width)


def test_wrong_width_is_a_clear_error():
    with pytest.raises(ValueError, match=r"expects \[\.\.\., 3\]"):
        PositionalEncoding(3, 4)(torch.zeros(2, 2))
