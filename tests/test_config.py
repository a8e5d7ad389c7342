"""Config: presets, overrides, unknown keys are errors, round trip through a dict."""

import pytest

from scenelabel.config import PRESETS, config_from_dict, config_to_dict, preset
from scenelabel.errors import ConfigError


def test_presets_resolve_and_round_trip():
    for name in PRESETS:
        config = preset(name)
        assert config.preset == name
        assert config_from_dict(config_to_dict(config)) == config


def test_overrides_apply_on_top_of_the_preset():
    config = preset("quick", {"train": {"steps": 7, "seed": 3}})
    assert config.train.steps == 7 and config.train.seed == 3
    assert config.field.channels == PRESETS["quick"]["field"]["channels"]


def test_unknown_keys_and_presets_are_errors():
    with pytest.raises(ConfigError, match="unknown train config key"):
        preset("fast", {"train": {"stepz": 1}})
    with pytest.raises(ConfigError, match="unknown config section"):
        config_from_dict({"trainer": {}})
    with pytest.raises(ConfigError, match="unknown preset"):
        preset("huge")


@pytest.mark.parametrize(
    "overrides",
    [
        {"field": {"class_head": "sigma"}},
        {"field": {"density_combine": "mean"}},
        {"field": {"semantic_rendering": "eq9"}},
        {"field": {"encoding": "hash"}},
        {"train": {"semantic_loss": "dice"}},
        {"train": {"focal_gamma": -1}},
    ],
)
def test_unknown_choices_are_errors(overrides):
    with pytest.raises(ConfigError, match="choose one of|focal_gamma"):
        preset("fast", overrides)
