"""The compiled hash encoding (``moegs/kernels/hashgrid.c``) against its torch reference
(``HashGrid.encode_reference``): the forward bit for bit, the table gradient up to the order of its
sums, determinism across thread counts, and when each path runs."""

from __future__ import annotations

import pytest
import torch

from moegs import kernels
from moegs.fields import DecomposedHashGrid4D, HashGrid

pytestmark = pytest.mark.skipif(
    not kernels.is_available(), reason=f"compiled CPU library not available ({kernels.load_error()})"
)

GRIDS = {
    # 3 levels: dense, hashed with a power-of-two table, hashed with a table smaller than 2^log2
    "mixed-3d": dict(input_dim=3, num_levels=3, level_dim=1, base_resolution=4, desired_resolution=16,
                     log2_hashmap_size=6),
    "grid4d-temporal": dict(input_dim=3, num_levels=32, level_dim=2, base_resolution=(8, 8, 8),
                            desired_resolution=(32, 32, 16), log2_hashmap_size=19),
    "grid4d-spatial": dict(input_dim=3, num_levels=16, level_dim=2, base_resolution=16,
                           desired_resolution=2048, log2_hashmap_size=12),
    "2d-wide-features": dict(input_dim=2, num_levels=5, level_dim=4, base_resolution=3, desired_resolution=40,
                             log2_hashmap_size=7),
    "1d": dict(input_dim=1, num_levels=4, level_dim=3, base_resolution=5, desired_resolution=50,
               log2_hashmap_size=4),
}  # fmt: skip


def make_grid(name: str, seed: int = 0) -> HashGrid:
    torch.manual_seed(seed)
    grid = HashGrid(**GRIDS[name])
    with torch.no_grad():
        grid.embeddings.uniform_(-1.0, 1.0)  # large values: rounding differences would show
    return grid


def make_points(grid: HashGrid, n: int = 3000, seed: int = 1) -> torch.Tensor:
    """Points in and around [0, 1]^D, with the corners 0 and 1 exactly and repeated points."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, grid.input_dim, generator=g) * 1.2 - 0.1
    k = n // 4
    u[:k] = u[k : 2 * k]  # repeated rows: gradient sums with many terms per table row
    u[2 * k], u[2 * k + 1] = 0.0, 1.0
    return u


@pytest.mark.parametrize("name", sorted(GRIDS))
def test_forward_is_bit_identical_to_the_reference(name):
    grid = make_grid(name)
    u = make_points(grid)
    with torch.no_grad():
        assert torch.equal(grid(u), grid.encode_reference(u))


def test_the_cases_cover_dense_hashed_and_non_power_of_two_tables():
    sizes = [(make_grid(n).dense, make_grid(n).sizes) for n in GRIDS]
    assert any(any(d) for d, _ in sizes) and not all(all(d) for d, _ in sizes)
    assert any(bool(((s & (s - 1)) != 0).any()) for _, s in sizes)


@pytest.mark.parametrize("name", sorted(GRIDS))
def test_table_gradient_matches_the_reference(name):
    grid = make_grid(name)
    u = make_points(grid)
    upstream = torch.randn(u.shape[0], grid.out_dim, generator=torch.Generator().manual_seed(2))
    (grid(u) * upstream).sum().backward()
    compiled, grid.embeddings.grad = grid.embeddings.grad, None
    (grid.encode_reference(u) * upstream).sum().backward()
    reference = grid.embeddings.grad
    scale = float(reference.abs().max())
    torch.testing.assert_close(compiled, reference, rtol=1e-5, atol=1e-6 * scale)
    assert torch.equal(compiled != 0, reference != 0)  # the same rows receive gradient


def test_outside_points_give_zero_and_nan_gives_nan_as_the_reference():
    grid = make_grid("mixed-3d")
    u = torch.tensor([[0.5, 1.2, 0.5], [-0.01, 0.5, 0.5], [float("nan"), 0.5, 0.5], [0.2, 0.3, 0.4]])
    with torch.no_grad():
        out, ref = grid(u), grid.encode_reference(u)
    assert out[:2].abs().sum() == 0 and out[2].isnan().all() and ref[2].isnan().all()
    assert torch.equal(out[[0, 1, 3]], ref[[0, 1, 3]])
    u = u[[0, 1, 3]]
    grid(u).sum().backward()
    rows = grid.embeddings.grad.abs().sum(1) > 0
    grid.embeddings.grad = None
    grid(u[2:]).sum().backward()
    assert torch.equal(rows, grid.embeddings.grad.abs().sum(1) > 0)  # outside points add no gradient


def test_results_do_not_depend_on_the_thread_count():
    grid = make_grid("grid4d-temporal")
    u = make_points(grid, n=20000)
    threads = torch.get_num_threads()
    results = []
    try:
        for count in (1, 2, 3):
            torch.set_num_threads(count)
            grid.embeddings.grad = None
            out = grid(u)
            out.square().sum().backward()
            results.append((out.detach(), grid.embeddings.grad))
    finally:
        torch.set_num_threads(threads)
    for out, grad in results[1:]:
        assert torch.equal(out, results[0][0]) and torch.equal(grad, results[0][1])


def test_inputs_that_need_a_gradient_take_the_reference(monkeypatch):
    grid = make_grid("mixed-3d")
    u = make_points(grid, n=64).clamp(0.0, 1.0).requires_grad_(True)
    calls = []
    monkeypatch.setattr(HashGrid, "encode_reference", lambda self, x: calls.append(x) or torch.zeros(1))
    grid(u)
    assert len(calls) == 1  # gradient to the points: only the reference computes it
    with torch.no_grad():
        grid(u)
    grid(u.detach().double().float())
    assert len(calls) == 1  # no gradient needed: compiled
    grid(u.detach().double())
    assert len(calls) == 2  # float64: reference


def test_without_the_library_the_reference_runs(monkeypatch):
    grid = make_grid("mixed-3d")
    u = make_points(grid, n=64)
    monkeypatch.setenv(kernels.DISABLE_ENV, "1")
    kernels.reset()
    try:
        assert not kernels.is_available()
        out = grid(u)
        assert out.grad_fn is not None and "Compiled" not in type(out.grad_fn).__name__
        assert torch.equal(out, grid.encode_reference(u))
    finally:
        monkeypatch.delenv(kernels.DISABLE_ENV)
        kernels.reset()
    assert "Compiled" in type(grid(u).grad_fn).__name__


def test_grid4d_encoder_matches_the_reference_end_to_end():
    """Grid4D's D-NeRF encoder (four grids, 16 + 3 x 32 levels): features and every table gradient."""
    torch.manual_seed(0)
    enc = DecomposedHashGrid4D()
    with torch.no_grad():
        for p in enc.parameters():
            p.uniform_(-0.5, 0.5)
    xyzt = torch.cat([torch.rand(4000, 3) * 3.0 - 1.5, enc.time_coordinate(torch.rand(4000, 1))], 1)
    grads = []
    for use_reference in (False, True):
        if use_reference:
            originals = {g: g.forward for g in [enc.spatial, *enc.temporal]}
            for g in originals:
                g.forward = g.encode_reference
        enc.zero_grad(set_to_none=True)
        h = torch.cat([enc.encode_spatial(xyzt[:, :3]), enc.encode_temporal(xyzt)], 1)
        h.sin().sum().backward()
        grads.append((h.detach(), [p.grad.clone() for p in enc.parameters()]))
    (h0, g0), (h1, g1) = grads
    assert torch.equal(h0, h1)
    for a, b in zip(g0, g1, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6 * float(b.abs().max()))
