"""Config: presets, overrides, unknown keys are errors, round trip through a dict."""

import dataclasses

import pytest

from scenelabel.config import (
    AUTO,
    AUTO_PRESET,
    PRESETS,
    DataConfig,
    FieldConfig,
    config_from_dict,
    config_to_dict,
    preset,
    with_preset,
)
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


def test_the_default_preset_is_auto_and_trains_as_fast_until_a_build_chooses():
    assert preset().preset == AUTO_PRESET
    assert dataclasses.replace(preset(), preset="fast") == preset("fast")


def test_the_default_preset_keeps_the_colour_live_and_rays_with_depth_on_a_random_colour():
    """Chosen on the scene suite (docs/suite_phone_depth_live.md): the default preset and fast get the
    live colour sigmoid; a preset not measured with it keeps the plain sigmoid, also when the build
    makes "auto" into it; every preset puts a random colour behind rays with depth."""
    assert preset().field.colour_live_logit == preset("fast").field.colour_live_logit == 4.0
    assert preset("voxels").field.colour_live_logit == with_preset(preset(), "voxels").field.colour_live_logit == 0.0
    assert {preset(name).train.depth_background for name in PRESETS} == {"random"}


def test_with_preset_carries_the_given_settings_and_the_presets_own():
    given = {"train": {"time_budget": 480.0, "seed": 3}, "field": {"grid_resolution": 64}}
    assert with_preset(preset(AUTO_PRESET, given), "voxels") == preset("voxels", given)
    # the preset's own settings come along: auto's time plan ("auto") replaces voxels' lack of one
    assert with_preset(preset(), "voxels") == preset("voxels", {"train": {"time_budget": AUTO}})
    assert with_preset(preset(), "fast") == preset("fast")
    # a setting given equal to the old preset's value is not told apart from one left alone
    assert with_preset(preset(AUTO_PRESET, {"sampling": {"n_steps": 288}}), "voxels").sampling.n_steps == 128
    assert with_preset(preset(AUTO_PRESET, {"sampling": {"n_steps": 256}}), "voxels").sampling.n_steps == 256
    # auto hands on its time plan only: the marching steps it shares with fast stay fast's
    assert with_preset(preset(), "voxels").sampling == preset("voxels").sampling
    quick = PRESETS["quick"]
    expected = preset("fast", {**quick, "train": {**quick["train"], "seed": 5}})
    assert with_preset(preset("quick", {"train": {"seed": 5}}), "fast") == expected


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
        {"train": {"distortion_weight": -0.01}},
        {"train": {"distortion_weight": float("nan")}},
        {"train": {"distortion_weight": True}},
        {"train": {"solid_weight": -1.0}},
        {"train": {"solid_weight": float("inf")}},
        {"train": {"solid_depth_steps": 0.0}},
        {"train": {"solid_depth_steps": float("nan")}},
        {"sampling": {"depth_ray_end": -1.0}},
        {"sampling": {"grid_decay": 0.0}},
        {"sampling": {"grid_decay": 1.5}},
        {"sampling": {"grid_decay": "fast"}},
        {"sampling": {"grid_from_training": "yes"}},
        {"sampling": {"depth_carve_until": 1.5}},
        {"sampling": {"depth_ray_end": float("inf")}},
        {"sampling": {"depth_ray_end": True}},
        {"sampling": {"train_min_trans": 1.0}},
        {"sampling": {"train_min_trans": -1e-4}},
        {"sampling": {"grid_reopen": 1.5}},
        {"sampling": {"grid_reopen": -0.01}},
        {"sampling": {"grid_reopen_until": True}},
        {"sampling": {"grid_reopen_by": "depth"}},
        {"sampling": {"grid_open_rays": -1}},
        {"sampling": {"grid_open_rays": 0.5}},
        {"sampling": {"grid_open_rays": True}},
        {"sampling": {"grid_open_rays": "many"}},
        {"sampling": {"grid_open_until": 2.0}},
        {"sampling": {"grid_open_labels": "uniform"}},
        {"sampling": {"train_min_trans": float("nan")}},
        {"sampling": {"train_min_trans": True}},
        {"train": {"background": "blue"}},
        {"train": {"distortion_start": 1.5}},
        {"train": {"distortion_start": -0.1}},
        {"train": {"free_margin": 1.0}},
        {"train": {"free_margin": -0.01}},
        {"train": {"free_margin": True}},
        {"train": {"free_margin": "wide"}},
        {"train": {"depth_background": "white"}},
        {"train": {"depth_background": None}},
        {"train": {"depth_background": "auto"}},  # no longer chosen by the cameras: "random" is the default
        {"train": {"background": [1.0, 2.0, 0.0]}},
        {"train": {"background": [1.0, 1.0]}},
        {"train": {"steps": -1}},
        {"train": {"steps": 1.5}},
        {"train": {"steps": "many"}},
        {"train": {"time_budget": 0.0}},
        {"train": {"time_budget": float("inf")}},
        {"train": {"time_budget": "soon"}},
    ],
)
def test_unknown_choices_are_errors(overrides):
    with pytest.raises(ConfigError, match="choose one of|steps|time_budget|focal_gamma|distortion_weight|solid_weight|solid_depth_steps|depth_ray_end|grid_decay|grid_from_training|depth_carve_until|background|distortion_start|free_margin|depth_background|train_min_trans|grid_reopen|grid_open"):
        preset("fast", overrides)


def test_distortion_weight_is_auto_or_a_number():
    """The default lets the build choose; a word other than "auto" names both accepted forms."""
    assert preset("fast").train.distortion_weight == "auto"
    assert preset("fast", {"train": {"distortion_weight": 0.01}}).train.distortion_weight == 0.01
    with pytest.raises(ConfigError, match='train.distortion_weight must be a finite number >= 0 or "auto", got \'often\''):
        preset("fast", {"train": {"distortion_weight": "often"}})


def test_a_background_is_a_colour_random_or_black():
    assert preset("fast", {"train": {"background": "random"}}).train.background == "random"
    assert preset("fast", {"train": {"background": [0, 0.5, 1]}}).train.background == (0, 0.5, 1)
    assert preset("fast", {"train": {"background": None}}).train.background is None


@pytest.mark.parametrize("downscale", [0, -2, 1.5, True, "2", None])
def test_data_downscale_must_be_a_positive_integer(downscale):
    with pytest.raises(ConfigError, match="data.downscale"):
        DataConfig(downscale=downscale)


@pytest.mark.parametrize("scale", [0, 0.0, -1, float("inf"), float("nan"), "1"])
def test_data_scale_must_be_positive_finite(scale):
    with pytest.raises(ConfigError, match="data.scale"):
        DataConfig(scale=scale)


@pytest.mark.parametrize("pad", [-0.01, 1.5, float("nan"), True, "0.1", None])
def test_data_bounds_pad_must_be_a_fraction(pad):
    with pytest.raises(ConfigError, match="data.bounds_pad"):
        DataConfig(bounds_pad=pad)


def test_data_section_round_trips_and_rejects_unknown_keys():
    config = config_from_dict({"data": {"downscale": 2, "scale": 0.5}})
    assert config.data == DataConfig(downscale=2, scale=0.5)
    assert config_from_dict(config_to_dict(config)) == config
    assert preset("quick").data == DataConfig()  # defaults: downscale 1, scale None
    assert DataConfig(downscale=4, scale=3).scale == 3
    with pytest.raises(ConfigError, match="unknown data config key"):
        config_from_dict({"data": {"downsample": 2}})


def test_sampling_warp_choices():
    for warp in ("auto", "box", "forward"):
        assert preset("quick", {"sampling": {"warp": warp}}).sampling.warp == warp
    assert preset("fast").sampling.warp == "auto"
    with pytest.raises(ConfigError, match="choose one of"):
        preset("fast", {"sampling": {"warp": "ndc"}})


def test_field_plane_cells_choices():
    assert FieldConfig().plane_cells == "square"  # checkpoints saved before the key load as they were built
    assert preset("quick", {"field": {"plane_cells": "cubic"}}).field.plane_cells == "cubic"
    with pytest.raises(ConfigError, match="field.plane_cells.*choose one of"):
        preset("fast", {"field": {"plane_cells": "round"}})


def test_data_layout_mounted_is_a_switch():
    assert DataConfig().layout_mounted is True and preset("fast").data.layout_mounted is True  # docs/suite_layout_mounted.md
    assert preset("quick", {"data": {"layout_mounted": False}}).data.layout_mounted is False
    with pytest.raises(ConfigError, match="data.layout_mounted must be true or false"):
        DataConfig(layout_mounted="yes")


def test_sampling_strategy_and_sample_counts():
    paper = preset("paper").sampling
    assert (paper.strategy, paper.n_coarse, paper.n_fine) == ("hierarchical", 64, 128)  # NeRF's coarse 64 + fine 128
    assert preset("fast").sampling.strategy == "grid"
    with pytest.raises(ConfigError, match="choose one of"):
        preset("fast", {"sampling": {"strategy": "proposal"}})
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ConfigError, match="sampling.n_fine"):
            preset("paper", {"sampling": {"n_fine": bad}})
