"""Configuration: presets, overrides with type coercion, clear errors, round trip through YAML."""

import pytest
import yaml

from osslam.config import Config, ConfigError, load_config, preset_names, save_config


def test_presets_exist_and_load():
    names = preset_names()
    for required in ("tum_fr1", "tum_fr2", "tum_fr3", "synthetic"):
        assert required in names
    assert load_config("tum_fr1").camera.model == "freiburg1"
    assert load_config("tum_fr3").camera.model == "freiburg3"


def test_overrides_are_coerced_to_field_types():
    cfg = load_config("tum_fr1", ["tracking.search_radius=22", "features.n_features=1500", "eval.plots=false",
                                  "camera.dist=[0.1, 0, 0, 0, 0]"])
    assert cfg.tracking.search_radius == 22.0 and isinstance(cfg.tracking.search_radius, float)
    assert cfg.features.n_features == 1500 and isinstance(cfg.features.n_features, int)
    assert cfg.eval.plots is False
    assert cfg.camera.dist == [0.1, 0.0, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("override", ["tracking.nope=1", "nosection.x=1", "tracking.search_radius=abc",
                                      "features.n_features=1.5", "missing_equals"])
def test_bad_overrides_raise_config_error(override):
    with pytest.raises(ConfigError):
        load_config(None, [override])


def test_unknown_preset_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="unknown config preset"):
        load_config("tum_fr9")
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "absent.yaml")


def test_invalid_yaml_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("tracking:\n  search_radius: 3\n  ratio: [unclosed\n")
    with pytest.raises(ConfigError) as err:
        load_config(bad)
    assert str(bad) in str(err.value) and "line" in str(err.value)


def test_saved_config_reloads_identically(tmp_path):
    cfg = load_config("tum_fr2", ["run.seed=7"])
    path = tmp_path / "config.yaml"
    save_config(cfg, path)
    assert yaml.safe_load(path.read_text())["run"]["seed"] == 7
    assert load_config(path) == cfg
    assert load_config(path) != Config()


def test_every_range_names_a_setting_whose_default_and_presets_lie_in_it():
    from osslam.config import RANGES, check_config

    cfg = Config()
    for key in RANGES:
        section, name = key.split(".")
        assert hasattr(getattr(cfg, section), name), key
    for name in [None, *preset_names()]:
        check_config(load_config(name))


@pytest.mark.parametrize("override, message", [
    ("fusion.inclusion_rate=1.5", "fusion.inclusion_rate must be within [0.0, 1.0], got 1.5"),
    ("flow.working_width=0", "flow.working_width must be at least 32, got 0"),
    ("motion.stride=0", "motion.stride must be at least 1, got 0"),
    ("fusion.dilation=-1", "fusion.dilation must be at least 0, got -1"),
    ("detection.score=-0.1", "detection.score must be within [0.0, 1.0], got -0.1"),
])
def test_settings_out_of_range_are_refused_naming_where_they_came_from(override, message):
    with pytest.raises(ConfigError) as error:
        load_config("tum_fr1", [override])
    assert str(error.value) == f"override '{override}': {message}"


def test_settings_out_of_range_in_a_file_or_in_code_are_refused(tmp_path):
    from osslam.system import System
    from osslam.types import CameraIntrinsics

    path = tmp_path / "mine.yaml"
    path.write_text("motion:\n  surface_fraction: 2\n")
    with pytest.raises(ConfigError, match=f"{path}: motion.surface_fraction must be within"):
        load_config(path)
    with pytest.raises(ConfigError, match=r"motion.min_depth \(7.0\) must be below motion.max_depth \(6.0\)"):
        load_config(None, ["motion.min_depth=7"])
    edge = load_config(None, ["fusion.inclusion_rate=1", "fusion.dilation=0", "flow.working_width=32"])  # bounds hold
    assert (edge.fusion.inclusion_rate, edge.fusion.dilation, edge.flow.working_width) == (1.0, 0, 32)
    cfg = Config()
    cfg.fusion.max_centre_distance = -5.0
    with pytest.raises(ConfigError, match="fusion.max_centre_distance must be at least 0.0, got -5.0"):
        System(cfg, CameraIntrinsics(525.0, 525.0, 319.5, 239.5))
