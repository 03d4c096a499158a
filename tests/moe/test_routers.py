"""MoE-GS routers on a tiny scene: convex gates, one-expert identity, frozen experts, exact geometry of
the weight splat, single pass == separate passes, per-frame experts' rows."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from helpers.scenes import tiny_scene

from moegs.experts import get_expert_class
from moegs.moe import MoEGS, RouterConfig
from moegs.moe.splat import expert_inputs, splat_experts
from moegs.render import frame_colors, rasterize
from moegs.render.projection import camera_points

ROUTERS = ("vapr", "pixel", "volume")


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(num_frames=3, cameras=3, size=24, num_points=120)


def make_expert(name: str, scene, seed: int = 0):
    cls = get_expert_class(name)
    config = cls.config_class.from_preset("quick")
    config = replace(config, train=replace(config.train, seed=seed))
    return cls.from_scene(scene, config).eval()


@pytest.fixture(scope="module")
def experts(scene):
    """A static 3DGS, per-frame 3DGS-MCMC (frame(t) is a subset of rows) and Ex4DGS (antialiased)."""
    return [make_expert("static", scene), make_expert("mcmc", scene, 1), make_expert("ex4dgs", scene, 2)]


def config(variant: str, **kw) -> RouterConfig:
    return replace(RouterConfig.from_preset("quick-paper"), variant=variant, **kw)


@pytest.mark.parametrize("variant", ROUTERS)
def test_gates_are_convex_at_every_pixel(scene, experts, variant):
    model = MoEGS(experts, config(variant))
    with torch.no_grad():
        for p in model.router.parameters():
            p.normal_()  # non-uniform routing
        out = model.render(scene.test[1].camera, scene.background)
    k, h, w = out.gates.shape
    assert (k, h, w) == (3, 24, 24) and out.image.shape == (24, 24, 3)
    assert out.expert_images.shape == (3, 24, 24, 3)
    assert (out.gates >= 0).all()
    torch.testing.assert_close(out.gates.sum(0), torch.ones(h, w))
    if variant != "volume":
        torch.testing.assert_close(out.image, (out.gates[..., None] * out.expert_images).sum(0))


@pytest.mark.parametrize("variant", ROUTERS)
def test_one_expert_moe_is_that_expert(scene, experts, variant):
    model = MoEGS(experts[:1], config(variant))
    camera = scene.test[0].camera
    with torch.no_grad():
        out = model.render(camera, scene.background)
        alone = experts[0].render(camera, scene.background)[0]
    tol = {"atol": 1e-4, "rtol": 0} if variant == "volume" else {"atol": 1e-6, "rtol": 0}
    torch.testing.assert_close(out.image, alone, **tol)
    torch.testing.assert_close(out.expert_images[0], alone, atol=1e-6, rtol=0)


@pytest.mark.parametrize("variant", ROUTERS)
def test_only_router_parameters_get_gradients(scene, experts, variant):
    model = MoEGS(experts, config(variant)).train()
    view = scene.train[4]
    out = model.render(view.camera, scene.background)
    (out.image - view.image()).abs().mean().backward()
    assert all(p.grad is None and not p.requires_grad for p in model.experts.parameters())
    router_grads = [p.grad for p in model.router.parameters()]
    assert router_grads and all(g is not None for g in router_grads)
    assert any(g.abs().sum() > 0 for g in router_grads)
    assert all(not e.training for e in model.experts)  # experts stay in eval mode


def test_weight_splat_uses_the_expert_geometry_at_t(scene, experts):
    """The splatted weight map of each expert equals a plain rasterize of that expert's frame(t) with the
    routing features as colours (and background 1 where nothing covers the pixel)."""
    model = MoEGS(experts, config("vapr"))
    with torch.no_grad():
        for p in [*model.router.weights.mix, *model.router.weights.time]:
            p.uniform_(-1, 1)
    camera = scene.train[4].camera  # t = 0.5
    router = model.router
    inputs = expert_inputs(experts, camera, scene.background)
    feats = [router.features(k, e, camera.time) for k, e in enumerate(experts)]
    splat = splat_experts(inputs, camera, extras=feats)
    for k, expert in enumerate(experts):
        frame = expert.frame(camera.time, camera)
        rows = expert.frame_rows(camera.time)
        mix = router.weights.mix[k] if rows is None else router.weights.mix[k][rows]
        time = router.weights.time[k] if rows is None else router.weights.time[k][rows]
        torch.testing.assert_close(feats[k][:, :2], mix)
        torch.testing.assert_close(feats[k][:, 2:], camera.time * time)  # t * w_time
        ref = rasterize(frame.with_colors(feats[k]), camera, antialiased=inputs[k].antialiased)
        torch.testing.assert_close(splat.extras[k], ref.image, atol=1e-5, rtol=0)
        torch.testing.assert_close(splat.alphas[k], ref.alpha, atol=1e-5, rtol=0)


def test_single_pass_equals_separate_renders(scene, experts):
    camera = scene.test[2].camera
    inputs = expert_inputs(experts, camera, scene.background)
    one = splat_experts(inputs, camera, single_pass=True)
    sep = splat_experts(inputs, camera, single_pass=False)
    assert one.passes == 2 and sep.passes == 3  # static + mcmc share a pass; ex4dgs is antialiased
    torch.testing.assert_close(one.images, sep.images, atol=1e-5, rtol=0)
    for k, expert in enumerate(experts):
        with torch.no_grad():
            torch.testing.assert_close(
                one.images[k], expert.render(camera, scene.background)[0], atol=1e-5, rtol=0
            )
    same_mode = splat_experts(inputs[:2], camera)
    assert same_mode.passes == 1


def test_an_expert_keeps_its_near_plane_in_a_shared_pass(scene):
    """The rasterizer culls at the expert's near plane (``ExpertConfig.near``) in its own render; a shared
    pass with an expert of another near plane gives the same image by zeroing those Gaussians' opacity."""
    camera = scene.test[0].camera
    near_expert, other = make_expert("static", scene), make_expert("mcmc", scene, 1)
    assert near_expert.config.near == other.config.near == 0.2  # the 3DGS rasterizer's in_frustum
    with torch.no_grad():
        depth = camera_points(near_expert.frame(camera.time).means, camera)[:, 2]
    cut = float(depth.median())
    near_expert.config = replace(near_expert.config, near=cut)  # drops the nearer half of its Gaussians
    inputs = expert_inputs([near_expert, other], camera, scene.background)
    with torch.no_grad():
        one = splat_experts(inputs, camera)
        image, out, _ = near_expert.render(camera, scene.background, return_stats=True)
        full = rasterize(inputs[0].frame, camera, background=scene.background)
    assert one.passes == 1
    torch.testing.assert_close(one.images[0], image, atol=1e-5, rtol=0)
    torch.testing.assert_close(one.images[1], other.render(camera, scene.background)[0], atol=1e-5, rtol=0)
    assert not out.info["visible"][depth <= cut].any() and out.info["visible"][depth > cut].any()
    assert (image - full.image).abs().max() > 0.05  # the near half was in view: culling it shows


def test_the_volume_router_keeps_an_experts_antialiasing_and_near_plane(scene):
    """The volume router renders its experts' Gaussians jointly; over one antialiased expert (Ex4DGS) whose
    near plane cuts half its Gaussians it still renders that expert (its gate is ~1)."""
    expert = make_expert("ex4dgs", scene, 2)
    camera = scene.test[0].camera
    with torch.no_grad():
        depth = camera_points(expert.frame(camera.time).means, camera)[:, 2]
    expert.config = replace(expert.config, near=float(depth.median()))
    model = MoEGS([expert], config("volume"))
    with torch.no_grad():
        out = model.render(camera, scene.background)
        alone = expert.render(camera, scene.background)[0]
    torch.testing.assert_close(out.image, alone, atol=1e-4, rtol=0)


def test_the_volume_gate_is_a_sigmoid_of_the_weight_plus_the_time_term(scene):
    expert = make_expert("static", scene)
    model = MoEGS([expert, make_expert("static", scene, 1)], config("volume"))
    weights = model.router.weights
    with torch.no_grad():
        weights.mix[0].normal_()
        weights.time[0].normal_()
        expected = torch.sigmoid(weights.mix[0][:, 0] + 0.5 * weights.time[0][:, 0])
        torch.testing.assert_close(model.router.gated(0, expert, 0.5), expected)


def test_the_pixel_router_sees_the_time(scene):
    """Two static experts render the same images at every time; the pixel router's logits still change
    with the time, its input channel."""
    model = MoEGS([make_expert("static", scene), make_expert("static", scene, 1)], config("pixel"))
    camera = scene.test[0].camera
    with torch.no_grad():
        for p in model.router.parameters():
            p.normal_()
        early = model.render(replace(camera, time=0.0), scene.background)
        late = model.render(replace(camera, time=1.0), scene.background)
    torch.testing.assert_close(early.expert_images, late.expert_images)
    assert (early.logits - late.logits).abs().max() > 1e-3


def test_the_pixel_router_starts_level_and_learns_at_the_codes_temperature(scene, experts):
    """Its output layer starts at zero: every expert the same logit, gates 1/K everywhere (a random output
    layer made the softmax at T = 0.01 one-hot from the first step, and the router never moved). A few
    steps at the code's training temperature then move the gates away from uniform."""
    from moegs.moe.train import router_param_groups
    from moegs.train.losses import photometric
    from moegs.train.optim import Optimizers

    torch.manual_seed(0)
    model = MoEGS(experts, config("pixel", train_temperature=0.01))
    view = scene.train[0]
    with torch.no_grad():
        start = model.render(view.camera, scene.background)
    torch.testing.assert_close(start.gates, torch.full_like(start.gates, 1 / 3))
    model.train()
    optimizers = Optimizers(router_param_groups(model))
    for step in range(1, 6):
        optimizers.set_step(step)
        out = model.render(view.camera, scene.background)
        photometric(out.image, view.image(), 0.2).backward()
        optimizers.step()
        optimizers.zero_grad()
    model.eval()
    with torch.no_grad():
        gates = model.render(view.camera, scene.background).gates
    assert (gates - 1 / 3).abs().max() > 0.05 and gates.max(0).values.min() < 0.99  # moved, not collapsed


def test_mixed_colour_widths_are_padded_and_decoded(scene):
    """An STG expert with the full feature model (9 channels + decoder) renders in the same pass as RGB."""
    stg = make_expert("stg", scene)
    assert stg.config.color == "full"
    static = make_expert("static", scene)
    camera = scene.test[0].camera
    inputs = expert_inputs([static, stg], camera, scene.background)
    assert frame_colors(inputs[1].frame, camera).shape[1] == 9
    with torch.no_grad():
        one = splat_experts(inputs, camera)
        torch.testing.assert_close(one.images[1], stg.render(camera, scene.background)[0], atol=1e-5, rtol=0)
    assert one.passes == 1


def test_phi_kernel_paper_and_code(experts):
    paper = MoEGS(experts, config("vapr")).router.phi
    code = MoEGS(experts, replace(RouterConfig.from_preset("code"), iterations=5)).router.phi
    assert [m.kernel_size for m in paper if hasattr(m, "kernel_size")] == [(3, 3)] * 3
    assert [m.kernel_size for m in code if hasattr(m, "kernel_size")] == [(1, 1)] * 3
    assert [(m.in_channels, m.out_channels) for m in code if hasattr(m, "in_channels")] == [
        (8, 6),
        (6, 3),
        (3, 1),
    ]
    assert all(m.bias is None for m in code if hasattr(m, "bias"))


def test_initial_routing_weights_follow_the_config(experts):
    paper = MoEGS(experts, config("vapr")).router.weights
    code = MoEGS(experts, RouterConfig.from_preset("code")).router.weights
    assert torch.equal(paper.mix[0][0], torch.tensor([0.9, 0.0])) and torch.equal(
        code.mix[0][0], torch.tensor([0.9, 0.9])
    )
    assert all(t.abs().sum() == 0 for t in paper.time)
    assert [p.shape[0] for p in paper.mix] == [e.num_gaussians for e in experts]


def test_temperature_applies_in_training_only():
    cfg = RouterConfig.from_preset("code")
    assert cfg.train_temperature == 0.01 and cfg.eval_temperature == 1.0
    assert RouterConfig.from_preset("paper").train_temperature == 1.0


@pytest.mark.parametrize("variant", ("vapr", "pixel"))
def test_gates_divide_the_logits_by_the_training_temperature_in_training_only(scene, experts, variant):
    """The code's ``softmax(logits / 0.01)`` while training, a plain softmax at evaluation."""
    model = MoEGS(experts, config(variant, train_temperature=0.01))
    with torch.no_grad():
        for p in model.router.parameters():
            p.normal_()
    camera = scene.test[1].camera
    for training, temperature in ((True, 0.01), (False, 1.0)):
        model.train(training)
        with torch.no_grad():
            out = model.render(camera, scene.background)
        torch.testing.assert_close(out.gates, torch.softmax(out.logits / temperature, dim=0))


def test_router_logits_are_the_weight_map_plus_phi(scene, experts):
    """``R'_k = w2D_k + Phi(w2D_dir_k, w2D_time_k, r)``, with the uncovered pixels' weights at the
    background value: with Phi zeroed the logits are the splatted ``w`` map alone."""
    model = MoEGS(experts, config("vapr"))
    router = model.router
    camera = scene.train[4].camera  # t = 0.5
    with torch.no_grad():
        for p in [*router.weights.mix, *router.weights.time]:
            p.uniform_(-1, 1)
        inputs = expert_inputs(experts, camera, scene.background)
        feats = [router.features(k, e, camera.time) for k, e in enumerate(experts)]
        splat = splat_experts(inputs, camera, extras=feats)
        w2d = splat.extras[..., 0] + (1.0 - splat.alphas) * router.config.weight_background
        assert (splat.alphas < 1e-3).any() and (splat.alphas > 0.5).any()  # both kinds of pixel
        for p in router.phi.parameters():
            p.zero_()
        torch.testing.assert_close(router.logits(splat.extras, splat.alphas, camera), w2d)
        for p in router.phi.parameters():
            p.normal_()
        residual = router.logits(splat.extras, splat.alphas, camera) - w2d
        assert residual.abs().max() > 1e-3  # a non-zero Phi moves the logits off the weight map


def test_bad_config_and_presets_are_named():
    with pytest.raises(ValueError, match="variant must be one of"):
        RouterConfig(variant="gate")
    with pytest.raises(ValueError, match="phi_kernel"):
        RouterConfig(phi_kernel=5)
    with pytest.raises(ValueError, match="valid presets: code, paper, quick, quick-paper"):
        RouterConfig.from_preset("fast")


def test_volume_router_refuses_feature_experts(scene):
    model = MoEGS([make_expert("static", scene), make_expert("stg", scene)], config("volume"))
    with pytest.raises(ValueError, match="must splat RGB"):
        model.render(scene.test[0].camera, scene.background)
