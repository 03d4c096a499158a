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
