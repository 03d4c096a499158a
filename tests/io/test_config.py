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
    back = from_dict(StaticConfig, data).strategy
    assert isinstance(back, MCMCStrategy) and back.cap_max == 7
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


@pytest.mark.parametrize(
    ("where", "type_name", "message"),
    [
        ("top", "os:system", "config _type 'os:system' is not StaticConfig or a moegs subclass of it"),
        ("top", "this:s", "config _type 'this:s' is not StaticConfig"),  # importing `this` prints
        ("top", "moegs.moe.config:RouterConfig", "is not StaticConfig or a moegs subclass of it"),
        ("strategy", "subprocess:Popen", "'subprocess:Popen' is not Strategy or a moegs subclass of it"),
        ("strategy", "moegs.experts.static:StaticConfig", "is not Strategy or a moegs subclass of it"),
        ("strategy", "moegs.nosuch:Thing", "'moegs.nosuch:Thing' is not Strategy"),
        ("strategy", 7, "config _type must be a 'module:Class' string, got 7"),
    ],
)
def test_only_registered_moegs_config_types_load(where, type_name, message):
    """A crafted checkpoint cannot make loading import or build anything but a moegs config class."""
    import sys

    data = to_dict(StaticConfig())
    (data if where == "top" else data[where])["_type"] = type_name
    module = str(type_name).partition(":")[0]
    imported = module in sys.modules
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        from_dict(StaticConfig, data)
    assert (module in sys.modules) == imported or module.startswith("moegs")
