import pytest
import torch

from moegs.gaussians import GaussianFrame, cat


def _frame(n, d=3, sh=False):
    quats = torch.nn.functional.normalize(torch.randn(n, 4), dim=1)
    kw = {"sh": torch.randn(n, 16, 3)} if sh else {"colors": torch.rand(n, d)}
    return GaussianFrame(torch.randn(n, 3), quats, torch.rand(n, 3) + 0.01, torch.rand(n), **kw)


def test_cat_returns_expert_ids_and_keeps_order():
    a, b = _frame(3), _frame(5)
    joined, ids = cat([a, b])
    assert len(joined) == 8
    assert ids.tolist() == [0, 0, 0, 1, 1, 1, 1, 1]
    torch.testing.assert_close(joined.means[3:], b.means)


def test_cat_rejects_mixed_colour_models():
    with pytest.raises(ValueError, match="mixes `sh` and `colors`"):
        cat([_frame(2), _frame(2, sh=True)])
    with pytest.raises(ValueError, match="colour shape"):
        cat([_frame(2, d=3), _frame(2, d=4)])


def test_shape_errors_name_the_field():
    f = _frame(4)
    with pytest.raises(ValueError, match=r"GaussianFrame.scales must have shape \[4, 3\]"):
        GaussianFrame(f.means, f.quats, torch.ones(4, 2), f.opacities, colors=f.colors)
    with pytest.raises(ValueError, match="exactly one of"):
        GaussianFrame(f.means, f.quats, f.scales, f.opacities)
    with pytest.raises(ValueError, match="bases"):
        GaussianFrame(f.means, f.quats, f.scales, f.opacities, sh=torch.zeros(4, 5, 3))


def test_check_finite_names_field():
    f = _frame(4)
    f.opacities[1] = float("nan")
    with pytest.raises(FloatingPointError, match="opacities"):
        f.check_finite()


def test_select_detach_and_sh_degree():
    f = _frame(6, sh=True)
    sub = f.select(torch.tensor([0, 2]))
    assert len(sub) == 2 and sub.sh_degree == 3 and sub.num_channels == 3
    w = f.with_colors(torch.ones(6, 7))
    assert w.sh is None and w.num_channels == 7
