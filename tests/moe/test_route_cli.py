"""Gate pictures and the ``moegs route`` command's argument errors."""

from __future__ import annotations

import numpy as np
import torch

from moegs.cli import main
from moegs.moe.visualize import PALETTE, weight_map, winner_map


def test_winner_map_colours_the_winner_and_whitens_ties():
    gates = torch.tensor([[[0.9, 0.5]], [[0.1, 0.5]]])  # K=2, H=1, W=2: expert 0 wins pixel 0; tie at pixel 1
    image = winner_map(gates)
    assert image.shape == (1, 2, 3) and image.dtype == np.uint8
    expected = 0.8 * PALETTE[0] + 0.2 * 255
    np.testing.assert_allclose(image[0, 0], expected.round(), atol=1)
    np.testing.assert_array_equal(image[0, 1], [255, 255, 255])


def test_weight_map_is_monotone_in_brightness():
    image = weight_map(torch.linspace(0, 1, 5)[None]).astype(float)
    assert image.shape == (1, 5, 3)
    brightness = image.mean(-1)[0]
    assert (np.diff(brightness) > 0).all()  # viridis goes dark -> bright


def test_route_rejects_unknown_expert_before_any_work(capsys, tmp_path):
    assert main(["route", "--experts", "nope", "--scene", "dnerf:mutant", "--out", str(tmp_path)]) == 2
    assert "unknown expert" in capsys.readouterr().err.lower()
    assert not any(tmp_path.iterdir())


def test_winner_share_ignores_uniform_pixels():
    from moegs.moe.model import winner_shares

    gates = torch.tensor([[[0.5, 0.9, 0.2, 0.5]], [[0.5, 0.1, 0.8, 0.5]]])
    assert winner_shares(gates) == [0.25, 0.25]
