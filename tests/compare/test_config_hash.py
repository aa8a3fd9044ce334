"""The identity of a scenario: every config key but [methods], named key by key when it differs."""

from __future__ import annotations

import math
from pathlib import Path

from compare.config import load_config, parse_config
from compare.config_hash import (
    config_fingerprint,
    config_hash,
    describe_differences,
    fingerprint_hash,
    method_settings,
)

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _with(config, section: str, **values):
    data = config.model_dump(mode="python")
    data[section].update(values)
    return parse_config(data)


def test_the_methods_are_not_part_of_the_hash_and_everything_else_is():
    config, _ = load_config(CONFIGS / "case1.toml")
    other_methods = _with(config, "methods", names=["mink"], settings={"mink": {"damping": 1e-3}})
    assert config_hash(other_methods) == config_hash(config)
    for section, values in [
        ("scenario", {"seed": 1}),
        ("scenario", {"duration_s": 71.0}),
        ("sensor", {"noise_std_m": 0.002}),
        ("solver_limit", {"period_fraction": 0.4}),
    ]:
        assert config_hash(_with(config, section, **values)) != config_hash(config), (section, values)


def test_the_fingerprint_is_flat_and_json_safe():
    config, _ = load_config(CONFIGS / "faults.toml")
    fingerprint = config_fingerprint(config)
    assert all(isinstance(k, str) for k in fingerprint)
    assert all(not isinstance(v, float) or math.isfinite(v) for v in fingerprint.values())
    assert "faults.inject[0].kind" in fingerprint and "levels[0].name" in fingerprint


def test_differences_are_named_scenario_keys_first():
    old = {"levels[0].name": "safety", "scenario.duration_s": 70.0, "sensor.rho_m": 0.5}
    new = {"levels[0].name": "walls", "scenario.duration_s": 28.0, "sensor.rho_m": 0.5, "scenario.x": 1}
    text = describe_differences(old, new, limit=2)
    assert text == 'scenario.duration_s 70.0 → 28.0, scenario.x "<unset>" → 1, and 1 more'


def test_method_settings_are_recorded_per_method():
    config, _ = load_config(CONFIGS / "case2.toml")
    config = _with(config, "methods", names=["tpik", "hqp-osqp"], settings={"hqp-osqp": {"eps_abs": 1e-6}})
    assert method_settings(config, "hqp-osqp") == {"eps_abs": 1e-6}
    assert method_settings(config, "tpik") == {}


def test_a_prediction_section_at_its_defaults_leaves_the_hash_of_the_config_without_it():
    """Results written before ``[prediction]`` existed stay results of the same config; setting it changes the hash."""
    config, _ = load_config(CONFIGS / "random.toml")
    fingerprint = config_fingerprint(config)
    assert any(k.startswith("prediction.") for k in fingerprint)
    without = {k: v for k, v in fingerprint.items() if not k.startswith("prediction.")}
    assert config_hash(config) == fingerprint_hash(without)
    predicted = config.model_copy(update={"prediction": config.prediction.model_copy(update={"mode": "estimated"})})
    assert config_hash(predicted) != config_hash(config)
