"""Config dataclasses survive a JSON round trip (every preset of every expert, nested strategy subclasses
included); dotted field edits (``with_fields``) and the field diffs runs are reused by (``config_changes``,
``changed_fields``)."""

import dataclasses
import json

import pytest

from moegs.experts.static import StaticConfig
from moegs.io import from_dict, to_dict
from moegs.io.config import changed_fields, config_changes, with_fields
from moegs.train.strategy import ADCStrategy, MCMCStrategy


def _every_preset_of_every_expert() -> list:
    from moegs.experts import get_expert_class, list_experts

    classes = [(spec.name, get_expert_class(spec.name).config_class) for spec in list_experts()]
    return [
        pytest.param(cls.from_preset(p), id=f"{name}-{p}")
        for name, cls in classes
        for p in cls.presets()
    ]


@pytest.mark.parametrize("config", _every_preset_of_every_expert())
def test_round_trip_through_json(config):
    """Every field of every expert's presets, tuples (E-D3DGS's ``deform``, STG's ``reset_at``) included."""
    data = to_dict(config)
    assert json.loads(json.dumps(data)) == data  # JSON-ready as it is: lists, dicts, numbers, strings
    assert from_dict(type(config), json.loads(json.dumps(data))) == config  # dataclass ==: classes too


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


def test_config_changes_are_dotted_and_skip_the_ignored():
    saved = to_dict(StaticConfig())
    current = to_dict(
        with_fields(StaticConfig(), {"train.iterations": 7, "train.checkpoint_every": 5, "near": 0.5})
    )
    assert config_changes(saved, current) == ["near", "train.checkpoint_every", "train.iterations"]
    assert config_changes(saved, current, ("train.checkpoint_every", "near")) == ["train.iterations"]


def test_with_fields_sets_nested_fields_inside_a_replaced_one():
    changed = with_fields(StaticConfig(), {"strategy": MCMCStrategy(), "strategy.cap_max": 7})
    assert changed.strategy == MCMCStrategy(cap_max=7)
    with pytest.raises(KeyError, match=r"StaticConfig.near is not a dataclass; cannot set \['x'\]"):
        with_fields(StaticConfig(), {"near.x": 1})


def test_changed_fields_name_a_nested_config_of_another_class_as_a_whole():
    mcmc = StaticConfig(strategy=MCMCStrategy())
    assert changed_fields(StaticConfig(), mcmc) == ["strategy"]
    assert changed_fields(mcmc, with_fields(mcmc, {"strategy.cap_max": 7})) == ["strategy.cap_max"]


@dataclasses.dataclass
class _Holder:
    table: dict = dataclasses.field(default_factory=lambda: {"window": (0, 16), "inner": ADCStrategy()})


def test_to_dict_converts_inside_dicts():
    data = to_dict(_Holder())["table"]
    assert data["window"] == [0, 16] and data["inner"] == to_dict(ADCStrategy())
