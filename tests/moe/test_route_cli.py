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


def test_a_finished_router_is_reused_only_for_the_same_config(tmp_path):
    """``moegs route`` skips a completed run of the same router config; another length trains again
    (only the checkpoint interval may differ)."""
    from dataclasses import replace

    from moegs.io import to_dict, write_json
    from moegs.moe import RouterConfig
    from moegs.route import finished_router

    config = RouterConfig.from_preset("quick")
    write_json(tmp_path / "config.json", {"router": to_dict(config)})
    assert finished_router(tmp_path, config) is None  # no metrics yet
    write_json(tmp_path / "metrics.json", {"completed": True, "step": config.iterations})
    assert finished_router(tmp_path, config) == {"completed": True, "step": config.iterations}
    assert finished_router(tmp_path, replace(config, checkpoint_every=7)) is not None
    assert finished_router(tmp_path, replace(config, iterations=config.iterations + 1)) is None
    assert finished_router(tmp_path, replace(config, variant="pixel")) is None
    write_json(tmp_path / "metrics.json", {"completed": False})
    assert finished_router(tmp_path, config) is None
