"""E-D3DGS: embedding interpolation, schedules, smoothness, sampling, and a real-data run."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene
from torch.nn import functional as F

from moegs.experts.ed3dgs import (
    ED3DGSConfig,
    ED3DGSExpert,
    buggy_temporal_tv,
    consecutive_pairs,
    embedding_smoothness,
    knn,
    knots_at,
    ramp,
    sample_rows,
    ssim_step,
    temporal_embedding,
)
from moegs.train.config import TrainConfig
from moegs.train.optim import Optimizers


def test_sample_rows_linear_and_reflected():
    table = torch.tensor([[0.0], [10.0], [20.0]])
    u = torch.tensor([0.0, 0.25, 0.5, 1.0, -0.25, 1.25])
    assert sample_rows(table, u)[:, 0].tolist() == pytest.approx([0.0, 5.0, 10.0, 20.0, 5.0, 15.0])


def test_temporal_embedding_resizes_before_sampling():
    table = torch.tensor([0.0, 4.0, 0.0, 4.0, 0.0])[:, None]  # 5 rows
    assert temporal_embedding(table, 0.25, 5).item() == pytest.approx(4.0)  # knot 1
    assert temporal_embedding(table, 0.25, 3).item() == pytest.approx(0.0)  # knots = rows 0, 2, 4: all zero
    assert temporal_embedding(table, 0.125, 5).item() == pytest.approx(2.0)  # half way to knot 1


def test_temporal_embedding_matches_the_original_interpolate_grid_sample():
    g = torch.Generator().manual_seed(1)
    table = torch.randn(150, 16, generator=g)
    for t, knots in [(0.0, 30), (0.37, 30), (0.91, 97), (1.0, 150), (1.08, 40), (-0.05, 40)]:
        resized = F.interpolate(table[None, None], size=(knots, 16), mode="bilinear", align_corners=True)
        grid = torch.stack([torch.arange(16) / 15, torch.full((16,), t)], dim=-1)[None, None]
        ref = F.grid_sample(
            resized, (grid - 0.5) * 2, mode="bilinear", padding_mode="reflection", align_corners=True
        )[0, 0, 0]
        assert torch.allclose(temporal_embedding(table, t, knots), ref, atol=2e-4), (t, knots)


def test_knot_schedule_and_ramps():
    assert [knots_at(s, 30, 150, 10_000) for s in (0, 5000, 10_000, 20_000)] == [30, 90, 150, 150]
    assert knots_at(123, 30, 150, None) == 150
    assert [ramp(s, 0, 1000) for s in (-5, 0, 250, 1000, 4000)] == [0.0, 0.0, 0.25, 1.0, 1.0]
    assert ramp(5500, 5000, 1000) == 0.5


def test_embedding_smoothness_by_hand():
    z = torch.tensor([[0.0, 0.0], [3.0, 4.0]])
    value = embedding_smoothness(z, torch.tensor([[1], [0]]), torch.tensor([[1.0], [0.25]]))
    assert value.item() == pytest.approx((5.0 + 2.5) / 2)
    # two neighbours each: a mean over Gaussians and neighbours, not a sum over neighbours
    value = embedding_smoothness(z, torch.tensor([[1, 1], [0, 0]]), torch.tensor([[1.0, 0.25], [1.0, 1.0]]))
    assert value.item() == pytest.approx((5.0 + 2.5 + 5.0 + 5.0) / 4)


def test_knn_on_a_line():
    pts = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [7.0, 0, 0]])
    d2, idx = knn(pts, 2)
    assert idx.tolist() == [[1, 2], [0, 2], [1, 0], [2, 1]]
    assert d2.tolist() == [[1.0, 9.0], [1.0, 4.0], [4.0, 9.0], [16.0, 36.0]]


def test_the_device_knn_finds_the_kd_trees_neighbours():
    """Off the CPU the neighbours come from ``knn_torch`` (float32 sums of squares): on points without ties
    they are the KD-tree's, at distances equal to rounding."""
    from moegs.data.points import knn_torch

    pts = torch.rand(300, 3, generator=torch.Generator().manual_seed(0))
    d2, idx = knn(pts, 20)
    d2_torch, idx_torch = knn_torch(pts, 20, max_elements=3000)  # several blocks of rows
    assert torch.equal(idx, idx_torch)
    torch.testing.assert_close(d2, d2_torch)


def test_the_smoothness_neighbours_follow_the_means_of_the_last_change_and_are_checkpointed():
    """Found for the means when the number of Gaussians changed (E-D3DGS), so a resume needs those means:
    they are extra state, and a restored expert finds the same neighbours as the one it was saved from."""
    expert, _ = _expert()
    expert.regularization(1)
    first = expert.knn_index
    with torch.no_grad():
        expert.splats["means"].add_(torch.randn_like(expert.splats["means"]))
    expert.regularization(2)
    assert expert.knn_index is first  # the same Gaussians: the same neighbours
    again, _ = _expert()
    again.load_state_dict(expert.state_dict())
    again.regularization(3)
    assert torch.equal(again.knn_index, first) and torch.equal(again.knn_weights, expert.knn_weights)


def test_buggy_temporal_tv_by_hand():
    w = torch.tensor([[0.0], [1.0], [3.0]])  # rows minus the LAST row, as in E-D3DGS
    first = torch.tensor([[1.0 - 3.0], [3.0 - 3.0]])
    second = first[1:] - first[1]
    assert buggy_temporal_tv(w).item() == pytest.approx(second.square().mean().item())
    # K = 4: first = w[1:] - w[3] = (-5, -3, 0); second = first[1:] - first[2] = (-3, 0)
    assert buggy_temporal_tv(torch.tensor([[0.0], [1.0], [3.0], [6.0]])).item() == pytest.approx(4.5)


def monocular(scene):
    """One camera per frame (cycling), as D-NeRF."""
    cams = len({v.camera.camera_id for v in scene.train})
    return replace(
        scene, train=[v for v in scene.train if v.camera.camera_id == v.camera.frame % cams], multiview=False
    )


def _expert(**overrides) -> tuple[ED3DGSExpert, object]:
    scene = tiny_scene()
    config = ED3DGSConfig.quick()
    for k, v in overrides.items():
        setattr(config, k, v)
    return ED3DGSExpert.from_scene(scene, config), scene


def test_ramp_in_and_delayed_attributes():
    expert, scene = _expert()
    c = expert.config
    assert expert.coefficients() == dict.fromkeys(("means", "quats", "scales", "opacities", "sh"), 0.0)
    expert.on_step(c.anneal_steps // 2)
    coef = expert.coefficients()
    assert coef["means"] == coef["quats"] == 0.5 and coef["scales"] == coef["opacities"] == coef["sh"] == 0.0
    expert.on_step(c.deform_from + c.anneal_steps)
    assert set(expert.coefficients().values()) == {1.0}


def test_untrained_embeddings_and_zero_ramp_give_the_canonical_frame():
    expert, scene = _expert()
    frame = expert.frame(0.3, scene.train[0].camera)  # step 0: every coefficient is 0
    assert torch.equal(frame.means, expert.splats["means"])
    expert.on_step(10_000)
    assert not torch.allclose(expert.frame(0.3, scene.train[0].camera).means, expert.splats["means"])


def test_knots_follow_the_schedule_in_training_and_at_test():
    """The original passes the iteration at test too (``render.py:54``): an early evaluation reads the
    interpolated knot count, the finished model the maximum."""
    expert, _ = _expert()
    c = expert.config
    half = c.coarse_to_fine_until // 2
    expert.on_step(half)
    fine = int(c.min_embeddings + (c.max_embeddings - c.min_embeddings) * half / c.coarse_to_fine_until)
    assert expert.knots() == (c.min_embeddings, fine)
    expert.eval()
    assert expert.knots() == (c.min_embeddings, fine)
    expert.train()
    expert.on_step(c.coarse_to_fine_until)
    assert expert.knots() == (c.min_embeddings, c.max_embeddings)
    expert.eval()
    assert expert.knots() == (c.min_embeddings, c.max_embeddings)


def test_camera_time_offsets_train_per_camera_and_average_at_test():
    expert, scene = _expert()
    offsets = expert.fields.offsets
    assert offsets.shape[0] == 1 + max(v.camera.camera_id for v in scene.train + scene.test)
    with torch.no_grad():
        offsets[0], offsets[2] = 0.1, 0.3
    assert float(expert.fields.time_offset(scene.train[2].camera, training=True).detach()) == pytest.approx(
        0.3
    )
    assert float(expert.fields.time_offset(None, training=False).detach()) == pytest.approx(0.2)
    at_test = expert.fields.time_offset(scene.train[2].camera, training=False)  # the mean, whichever camera
    assert float(at_test.detach()) == pytest.approx(0.2)
    mono = ED3DGSExpert.from_scene(monocular(tiny_scene()), ED3DGSConfig.quick())
    assert mono.fields.offsets is None and mono.views is None


def test_regularization_by_hand():
    """``sigmoid(mean opacity logit)`` x ``opacity_reg`` plus the embedding smoothness over each Gaussian's
    ``k`` nearest neighbours weighted ``exp(-2000 d²)`` (``train.py``, ``weighted_l2_loss_v2``)."""
    expert, _ = _expert(smoothness_neighbours=3, temporal_tv=0.0)
    c, s = expert.config, expert.splats
    with torch.no_grad():
        s["opacities"].copy_(torch.linspace(-1.0, 3.0, len(s["opacities"])))  # sigmoid of mean != mean of
        s["embedding"].normal_()
    means = s["means"].detach().double()
    d2 = (means[:, None] - means[None]).square().sum(-1)
    d2.fill_diagonal_(float("inf"))
    near, idx = d2.topk(3, largest=False)  # brute force in float64, not the KD-tree
    weights = torch.exp(-c.smoothness_falloff * near.float())
    diff = s["embedding"][:, None, :] - s["embedding"][idx]
    smooth = torch.sqrt(diff.square().sum(-1) * weights + 1e-20).mean()
    expected = c.opacity_reg * torch.sigmoid(s["opacities"].mean()) + c.smoothness_reg * smooth
    assert c.smoothness_falloff == 2000.0 and c.opacity_reg > 0 and c.smoothness_reg > 0
    torch.testing.assert_close(expert.regularization(1), expected, rtol=1e-5, atol=1e-7)


def test_the_deformation_learning_rate_decays_between_scaled_ends():
    from moegs.train.schedules import group_lr

    expert, _ = _expert()
    c, sc = expert.config, expert.spatial_lr_scale
    group = next(g for g in expert.param_groups() if g.name == "deformation")
    assert sc != 1.0
    assert group_lr(group, 0) == pytest.approx(c.deformation_lr * sc)
    assert group_lr(group, c.deformation_lr_max_steps) == pytest.approx(c.deformation_lr_final * sc)


def test_multiview_ssim_steps_add_half_a_dssim_and_release_their_frame():
    """``train.py``: ``λ (1 - SSIM) / 2`` on the SSIM iterations; after them the kept frame is released."""
    from moegs.train.losses import dssim

    expert, scene = _expert(random_until=0, multiview_ssim_iters=5, lambda_ssim=1.0)
    view = scene.train[0]
    g = torch.Generator().manual_seed(0)
    rgb, target = torch.rand(32, 32, 3, generator=g), torch.rand(32, 32, 3, generator=g)
    assert float(expert.observe(50, view, rgb, target, None)) == pytest.approx(float(dssim(rgb, target)) / 2)
    assert expert.observe(55, view, rgb, target, None) is None
    expert.select_views(54, scene.train, 1, g)
    assert int(expert.views.kept_frame) >= 0  # step 54 keeps its frame for step 55
    expert.select_views(55, scene.train, 1, g)
    assert int(expert.views.kept_frame) == -1


def test_every_parameter_in_exactly_one_group():
    expert, _ = _expert()
    opts = Optimizers(expert.param_groups())
    assert set(opts.for_splats(expert.splats)) == set(expert.splats.keys())
    grouped = [p for g in expert.param_groups() for p in g.params]
    assert len(grouped) == len({id(p) for p in grouped}) == len(list(expert.parameters()))


def test_sampler_keeps_consecutive_cameras_apart_and_reuses_ssim_frames():
    expert, scene = _expert(random_until=0, multiview_ssim_iters=5)
    table, g = expert.views, torch.Generator().manual_seed(0)
    cams = []
    for step in range(1, 60):
        (i,) = expert.select_views(step, scene.train, 1, g)
        cams.append(scene.train[i].camera)
    for a, b in zip(cams[:-1], cams[1:], strict=True):
        assert float((a.center - b.center).norm()) >= table.min_distance - 1e-6
    # step % 50 in 0..4 keeps the frame for the next step: steps 50..55 share one frame
    assert len({c.frame for c in cams[49:55]}) == 1


def test_multiview_ssim_steps_are_the_first_of_every_50_after_random_until():
    """``train.py:125``: ``iteration >= random_until and iteration % 50 < num_multiview_ssim``."""
    config = replace(ED3DGSConfig.quick(), random_until=100, multiview_ssim_iters=5)
    assert [s for s in range(0, 260) if ssim_step(s, config)] == [
        *range(100, 105),
        *range(150, 155),
        *range(200, 205),
        *range(250, 255),
    ]
    assert not any(ssim_step(s, replace(config, multiview_ssim_iters=0)) for s in range(300))


def test_monocular_batches_are_consecutive_pairs_of_training_images():
    """``train.py:110-113``: ``max(B // 2, 1)`` draws of ``f < ⌈n / 2⌉``, images ``2f`` then ``2f + 1``
    modulo the frame count (``scene.maxtime``): 5 images of 5 frames pair as (0, 1), (2, 3) and (4, 0)."""
    g = torch.Generator().manual_seed(0)
    pairs = {tuple(consecutive_pairs(5, 5, 2, g)) for _ in range(200)}
    assert pairs == {(0, 1), (2, 3), (4, 0)}
    batch = consecutive_pairs(6, 6, 4, g)
    assert len(batch) == 4 and [i + 1 for i in batch[:2]] == batch[2:]
    assert len(consecutive_pairs(6, 6, 1, g)) == 2  # a batch of 1 still draws a pair, as the original
    # 6 images of 3 frames: draws f < 3 as from the image count, indices wrap at the frame count
    pairs = {tuple(consecutive_pairs(6, 3, 2, g)) for _ in range(200)}
    assert pairs == {(0, 1), (2, 0), (1, 2)}


def test_select_views_pairs_only_monocular_scenes_of_the_pairing_recipe():
    expert, scene = _expert()
    g = torch.Generator().manual_seed(0)
    assert expert.views is not None and len(expert.select_views(1, scene.train, 2, g)) == 2  # multi-view
    expert.views = None  # a monocular scene's expert has no multi-view table
    assert expert.select_views(1, scene.train, 2, g) is None  # the default sampler
    expert.config.consecutive_pairs = True
    frames = len({view.camera.frame for view in scene.train})
    assert frames < len(scene.train)  # several cameras a frame: the pairs wrap at the frame count
    draws = [expert.select_views(1, scene.train, 2, g) for _ in range(50)]
    assert all(b == (a + 1) % frames and a < frames for a, b in draws)


def test_quick_keeps_one_view_a_step_on_hypernerf():
    from moegs.recipes import config_for

    assert config_for("ed3dgs", "hypernerf:chicken", "paper").config.consecutive_pairs
    quick = config_for("ed3dgs", "hypernerf:chicken", "quick").config
    assert not quick.consecutive_pairs and quick.train.batch_size == 1


def test_the_error_table_is_saved_and_restored_with_the_expert():
    """The per-camera, per-frame errors steer the sampler after a resume: they are state, not a cache."""
    expert, scene = _expert(random_until=0)
    with torch.no_grad():
        expert.views.errors.fill_(0.1)
        expert.views.errors[:, 1] = 0.7
    state = expert.state_dict()
    assert "views.errors" in state
    again, _ = _expert(random_until=0)
    again.load_state_dict(state)
    torch.testing.assert_close(again.views.errors, expert.views.errors)


def test_error_guided_frames_prefer_high_error():
    expert, scene = _expert(random_until=0, multiview_ssim_iters=0)
    with torch.no_grad():
        expert.views.errors.fill_(0.1)
        expert.views.errors[:, 2] = 0.9
    g = torch.Generator().manual_seed(0)
    frames = [scene.train[expert.select_views(s, scene.train, 1, g)[0]].camera.frame for s in range(2, 80, 2)]
    assert all(f == 2 for f in frames)  # min-max normalised: the lowest-error frames get probability 0


def test_trains_on_tiny_scene_and_beats_its_start():
    scene = tiny_scene()
    config = ED3DGSConfig.quick()
    config.train = TrainConfig(iterations=30, lambda_dssim=0.0)
    expert = ED3DGSExpert.from_scene(scene, config)
    from moegs.train.evaluate import evaluate
    from moegs.train.loop import train

    start = evaluate(expert.eval(), scene.test, scene.background)["psnr"]
    result = train(expert, scene, progress=False)
    assert math.isfinite(result["final_loss"]) and result["test"]["psnr"] > start + 1.0, (start, result)
    assert expert.splats["embedding"].abs().sum() > 0  # the per-Gaussian embeddings learned
