"""Every registered expert (built-in and installed plugins) follows the expert protocol: shapes,
activated ranges, a deterministic ``frame(t)``, gradients reaching the trained tensors, checkpoints that
round-trip (``helpers.protocol``)."""

from __future__ import annotations

import pytest
from helpers.protocol import check_protocol

from moegs.experts import list_experts


@pytest.mark.parametrize("name", [s.name for s in list_experts() if not s.composite])
def test_expert_follows_the_protocol(name, tmp_path):
    check_protocol(name, tmp_path)


@pytest.mark.parametrize("name", [s.name for s in list_experts() if not s.composite])
def test_presets_name_every_dataset_config(name):
    """``paper`` is the field defaults, ``paper-<dataset>`` each ``paper_<dataset>`` classmethod (and the
    defaults' own dataset), ``quick`` the reduction; each preset builds its config class."""
    from moegs.experts import get_expert_class

    cls = get_expert_class(name).config_class
    presets = cls.presets()
    methods = {f"paper-{a.removeprefix('paper_')}" for a in dir(cls) if a.startswith("paper_")}
    default = {f"paper-{cls.DEFAULT_DATASET}"} if cls.DEFAULT_DATASET else set()
    assert {"paper", "quick"} | methods | default <= set(presets)
    assert cls.from_preset("paper") == cls()
    for dataset_preset in default:
        assert cls.from_preset(dataset_preset) == cls()
    for preset in presets:
        assert isinstance(cls.from_preset(preset), cls), preset
    for entry in cls.DATASET_PRESETS.values():
        assert entry.preset in presets


def test_near_planes_are_the_original_rasterizers():
    """The 3DGS rasterizer culls at view depth <= 0.2 in every dataset; Ex4DGS's culls at its dataset's
    near (N3V 4.0 in N3V's own frame, Technicolor 0.01, else 0.2)."""
    from moegs.experts.base import NEAR_3DGS
    from moegs.recipes import config_for

    assert NEAR_3DGS == 0.2
    for name in ("static", "mcmc", "deformable", "fourdgs", "grid4d", "ed3dgs", "stg", "mode"):
        for scene in ("dnerf:mutant", "panoptic:basketball", "synthetic:n3v_like"):
            assert config_for(name, scene, "paper").config.near == NEAR_3DGS, (name, scene)
    assert config_for("ex4dgs", "panoptic:basketball", "paper").config.near == NEAR_3DGS
    assert config_for("ex4dgs", "synthetic:n3v_like", "paper").config.near == NEAR_3DGS  # not N3V's frame
    assert config_for("ex4dgs", "n3v:coffee_martini", "paper").config.near == 4.0
    assert config_for("ex4dgs", "technicolor:Birthday", "paper").config.near == 0.01
