"""The CUDA path (``backend="cuda"``, ``_cuda.py``) against our torch reference, twice: without a GPU, our
gsplat glue runs with gsplat's own pure-PyTorch kernels on CPU tensors (``helpers.gsplat_reference``);
with a GPU and gsplat installed, the same tests run gsplat's CUDA kernels on CUDA tensors.

Where gsplat's conventions and 3DGS's cannot differ (opacity <= 0.3: alpha never reaches either clamp and
every Gaussian's 1/255 footprint lies inside both screen radii), the two agree to float32 rounding:
images, alphas, depths, per-Gaussian statistics and every gradient. At full opacity they differ only by
the documented clamps (``_cuda.py`` docstring). Single pass on CUDA is one batched gsplat call and
equals K separate renders.
"""

from __future__ import annotations

import importlib.util
import types
from typing import NamedTuple

import helpers.gsplat_reference as gsplat_reference
import pytest
import torch

from moegs import Camera, GaussianFrame
from moegs.camera import intrinsics, look_at
from moegs.render import _cuda, rasterize, rasterize_multi

FIELDS = ("means", "quats", "scales", "opacities")


class Glue(NamedTuple):
    module: types.ModuleType  # the gsplat module ``_cuda.render`` calls (patch its ``rasterization``)
    device: torch.device


def _has_gsplat_cuda() -> bool:
    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


@pytest.fixture(
    params=[
        "torch-kernels-on-cpu",
        pytest.param(
            "cuda", marks=pytest.mark.skipif(not _has_gsplat_cuda(), reason="needs CUDA and gsplat")
        ),
    ]
)
def glue(request, monkeypatch) -> Glue:
    """gsplat on CUDA, or gsplat patched to its torch kernels with ``_cuda`` accepting CPU tensors."""
    if request.param == "cuda":
        import gsplat

        return Glue(gsplat, torch.device("cuda"))
    return Glue(gsplat_reference.install_cpu_glue(monkeypatch), torch.device("cpu"))


def _camera(width: int = 40, height: int = 30) -> Camera:
    """Off-axis principal point, a rotated and translated pose looking at the origin."""
    K = intrinsics(1.1 * width, 1.1 * width, 0.45 * width, 0.55 * height)
    w2c = look_at(torch.tensor([1.2, -0.6, -3.5]), torch.zeros(3))
    return Camera(K=K, world_to_camera=w2c, width=width, height=height, near=0.2, far=20.0)


def _frame(
    n: int, *, opacity: tuple[float, float], sh_degree: int | None = 1, seed: int = 0
) -> GaussianFrame:
    """``n`` Gaussians around the origin (inside ``_camera``'s view), colours as SH of ``sh_degree``."""
    gen = torch.Generator().manual_seed(seed)
    means = 1.4 * (torch.rand(n, 3, generator=gen) - 0.5)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1)
    scales = 0.03 + 0.06 * torch.rand(n, 3, generator=gen)
    opacities = opacity[0] + (opacity[1] - opacity[0]) * torch.rand(n, generator=gen)
    if sh_degree is None:
        return GaussianFrame(means, quats, scales, opacities, colors=torch.rand(n, 3, generator=gen))
    sh = 0.4 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen)
    return GaussianFrame(means, quats, scales, opacities, sh=sh)


def _fields(frame: GaussianFrame) -> tuple[str, ...]:
    return (*FIELDS, "sh" if frame.sh is not None else "colors")


def _render_with_grads(render, frames):
    """``(outputs, grads)``: ``render`` of fresh leaf copies of ``frames``, then one fixed backward."""
    leaves = [
        GaussianFrame(**{k: getattr(f, k).detach().clone().requires_grad_(True) for k in _fields(f)})
        for f in frames
    ]
    out = render(leaves)
    images = out.images if hasattr(out, "images") else out.image
    alphas = out.alphas if hasattr(out, "alphas") else out.alpha
    depths = out.depths if hasattr(out, "depths") else out.depth
    weights = torch.linspace(0.1, 1.0, images.shape[-3:].numel(), device=images.device)  # same per expert
    weights = weights.view(images.shape[-3:])
    ((images * weights).sum() + 0.3 * alphas.sum() + 0.05 * depths.sum()).backward()
    grads = [getattr(f, k).grad for f in leaves for k in _fields(f)]
    return out, grads + [out.info["means2d"].grad]


def _assert_grads_close(got, ref, rel):
    for a, b in zip(got, ref, strict=True):
        torch.testing.assert_close(a.cpu(), b.cpu(), rtol=rel, atol=rel * float(b.abs().max()))


@pytest.mark.parametrize("antialiased", [False, True])
def test_glue_matches_torch_reference_where_conventions_agree(glue, antialiased):
    cam = _camera()
    frame = _frame(40, opacity=(0.05, 0.3))
    background = torch.tensor([0.2, 0.5, 0.9])

    def render(backend, device):
        camera, back = cam.to(device), background.to(device)
        return lambda fs: rasterize(
            fs[0], camera, background=back, antialiased=antialiased, return_stats=True, backend=backend
        )

    ref, ref_grads = _render_with_grads(render("torch", "cpu"), [frame])
    got, got_grads = _render_with_grads(render("cuda", glue.device), [frame.to(glue.device)])
    assert got.info["backend"] == "cuda" and got.image.device.type == glue.device.type
    for a, b in ((got.image, ref.image), (got.alpha, ref.alpha), (got.depth, ref.depth)):
        torch.testing.assert_close(a.cpu(), b, atol=2e-5, rtol=0)
    assert ref.alpha.amax() > 0.5  # overlapping splats, not a sparse scene
    assert torch.equal(got.info["visible"].cpu(), ref.info["visible"]) and ref.info["visible"].sum() > 30
    torch.testing.assert_close(got.info["contrib"].cpu(), ref.info["contrib"], atol=1e-4, rtol=1e-4)
    _assert_grads_close(got_grads, ref_grads, rel=2e-3)


def test_glue_at_full_opacity_differs_only_by_the_documented_clamps(glue):
    cam = _camera()
    frame = _frame(60, opacity=(0.3, 1.0), sh_degree=None)
    ref = rasterize(frame, cam, backend="torch")
    got = rasterize(frame.to(glue.device), cam.to(glue.device), backend="cuda")
    diff = (got.image.cpu() - ref.image).abs()
    assert float(diff.mean()) < 2e-3 and float(diff.max()) < 0.05
    torch.testing.assert_close(got.alpha.cpu(), ref.alpha, atol=0.02, rtol=0)


def test_glue_culls_like_the_reference(glue):
    cam = _camera(24, 18)
    frame = _frame(12, opacity=(0.1, 0.3), sh_degree=None)
    centre = torch.linalg.inv(cam.world_to_camera)[:3, 3]
    moved = frame.means.clone()
    moved[0] = centre - 2.0 * (torch.zeros(3) - centre)  # behind the camera
    moved[1] = torch.tensor([40.0, 0.0, 0.0])  # far outside the image
    frame = GaussianFrame(moved, frame.quats, frame.scales, frame.opacities, colors=frame.colors)
    got = rasterize(frame.to(glue.device), cam.to(glue.device), return_stats=True, backend="cuda")
    ref = rasterize(frame, cam, return_stats=True, backend="torch")
    assert not got.info["visible"][:2].any()
    assert torch.equal(got.info["visible"].cpu(), ref.info["visible"])


def test_single_pass_is_one_gsplat_call_equal_to_separate_renders(glue, monkeypatch):
    cam = _camera(32, 24).to(glue.device)
    frames = [_frame(n, opacity=(0.05, 0.6), seed=s).to(glue.device) for s, n in ((1, 25), (2, 9), (3, 17))]
    calls = []
    rasterization = glue.module.rasterization
    monkeypatch.setattr(
        glue.module, "rasterization", lambda *a, **k: calls.append(1) or rasterization(*a, **k)
    )
    backgrounds = torch.tensor([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.3, 0.6, 0.1]], device=glue.device)

    multi, multi_grads = _render_with_grads(
        lambda fs: rasterize_multi(fs, cam, backgrounds=backgrounds, return_stats=True, backend="cuda"),
        frames,
    )
    assert len(calls) == 1
    separate = [
        _render_with_grads(
            lambda fs, k=k: rasterize(
                fs[0], cam, background=backgrounds[k], return_stats=True, backend="cuda"
            ),
            [f],
        )
        for k, f in enumerate(frames)
    ]
    assert len(calls) == 4
    sizes = [len(f) for f in frames]
    for k, (one, _) in enumerate(separate):
        torch.testing.assert_close(multi.images[k], one.image, atol=1e-6, rtol=0)
        torch.testing.assert_close(multi.alphas[k], one.alpha, atol=1e-6, rtol=0)
        torch.testing.assert_close(multi.depths[k], one.depth, atol=1e-5, rtol=0)
    for key in ("radii", "contrib"):
        torch.testing.assert_close(multi.info[key], torch.cat([one.info[key] for one, _ in separate]))
    means2d_grads = torch.cat([grads[-1] for _, grads in separate])
    field_grads = [g for _, grads in separate for g in grads[:-1]]
    _assert_grads_close(multi_grads, field_grads + [means2d_grads], rel=1e-5)
    cpu_frames = [f.to("cpu") for f in frames]
    torch_multi = rasterize_multi(cpu_frames, cam.to("cpu"), backgrounds=backgrounds.cpu(), backend="torch")
    torch.testing.assert_close(multi.images.cpu(), torch_multi.images, atol=0.02, rtol=0)
    assert sizes == [25, 9, 17]


def test_groups_are_padded_to_at_least_a_warp():
    """gsplat's batched projection backward mixes batches inside a warp when a batch holds < 32 Gaussians
    (``_cuda.MIN_GROUP_WIDTH``); the ``[cuda]`` variant of the single-pass test above failed without this."""
    groups = torch.tensor([0] * 25 + [1] * 9 + [2] * 17)
    slot, width = _cuda._padded_layout(groups, 3)
    assert width == 32 and torch.equal(slot // width, groups) and len(set(slot.tolist())) == len(groups)
    assert _cuda._padded_layout(torch.zeros(5, dtype=torch.long), 1)[1] == 5  # one group: no padding
    assert _cuda._padded_layout(torch.tensor([0] * 40 + [1] * 3), 2)[1] == 40


def test_single_pass_with_an_empty_expert(glue):
    cam = _camera(24, 18).to(glue.device)
    full = _frame(10, opacity=(0.1, 0.3), sh_degree=None).to(glue.device)
    empty = GaussianFrame(*(getattr(full, k)[:0] for k in FIELDS), colors=full.colors[:0])
    out = rasterize_multi([full, empty], cam, return_stats=True, backend="cuda")
    torch.testing.assert_close(out.images[0], rasterize(full, cam, backend="cuda").image, atol=1e-6, rtol=0)
    assert float(out.alphas[1].abs().max()) == 0.0 and out.info["radii"].shape == (10,)


def test_vectorised_tile_intersection_equals_gsplats_loop():
    import gsplat.cuda._torch_impl as impl

    gen = torch.Generator().manual_seed(5)
    means2d = torch.rand(2, 30, 2, generator=gen) * torch.tensor([70.0, 50.0]) - 5
    radii = torch.randint(0, 20, (2, 30, 2), generator=gen, dtype=torch.int32)
    radii[0, :4] = 0  # culled
    depths = torch.rand(2, 30, generator=gen) + 0.5
    ours = gsplat_reference.isect_tiles(means2d, radii, depths, 16, 4, 3)
    theirs = impl._isect_tiles(means2d, radii, depths, 16, 4, 3)
    for a, b in zip(ours, theirs, strict=True):
        assert torch.equal(a, b)
