"""Config dataclasses survive a JSON round trip, nested strategy subclasses included."""

import json

import pytest

from moegs.experts.mcmc import MCMCConfig
from moegs.experts.static import StaticConfig
from moegs.io import from_dict, to_dict
from moegs.train.strategy import ADCStrategy, MCMCStrategy


@pytest.mark.parametrize(
    "config",
    [StaticConfig.from_preset("quick"), StaticConfig.from_preset("paper"), MCMCConfig.from_preset("quick")],
)
def test_round_trip_through_json(config):
    back = from_dict(type(config), json.loads(json.dumps(to_dict(config))))
    assert back == config
    assert type(back.strategy) is type(config.strategy)


def test_base_typed_field_restores_subclass():
    data = to_dict(StaticConfig(strategy=MCMCStrategy(cap_max=7)))
    assert isinstance(from_dict(StaticConfig, data).strategy, MCMCStrategy)
    assert isinstance(from_dict(StaticConfig, to_dict(StaticConfig())).strategy, ADCStrategy)


def test_unknown_keys_are_named():
    data = to_dict(StaticConfig())
    data["sh_degre"] = 2
    with pytest.raises(ValueError, match=r"StaticConfig: unknown config keys \['sh_degre'\]"):
        from_dict(StaticConfig, data)


def test_presets_are_named():
    with pytest.raises(
        ValueError, match="unknown preset 'fast' for StaticConfig; valid presets: paper, quick"
    ):
        StaticConfig.from_preset("fast")
