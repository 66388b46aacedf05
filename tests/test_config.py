"""The root config: defaults, YAML round trip, strict keys and types."""

from __future__ import annotations

from pathlib import Path

import pytest

from factorloc import Config, ConfigError


def test_yaml_round_trip_keeps_every_value(tmp_path: Path) -> None:
    cfg = Config.from_dict({"odometry": {"max_sigma_position_m": 0.06}, "fusion": {"strategy": "product"}})
    path = tmp_path / "c.yaml"
    cfg.to_yaml(path)
    assert Config.from_yaml(path) == cfg
    assert Config.from_yaml(path).odometry.max_sigma_position_m == 0.06


@pytest.mark.parametrize(
    "data,match",
    [
        ({"odometri": {}}, r"config has unknown key\(s\) \['odometri'\] \(did you mean 'odometry'\?\)"),
        ({"odometry": {"max_sigma": 1}}, r"config.odometry has unknown key"),
        ({"odometry": {"enabled": "yes"}}, "config.odometry.enabled must be true or false"),
        ({"odometry": {"max_sigma_position_m": "big"}}, "config.odometry.max_sigma_position_m must be a real number, got str"),
        ({"fusion": {"strategy": "average"}}, "fusion.strategy"),
        ({"gating": {"consistency_probability": 1.5}}, "consistency_probability"),
        ({"gating": 3}, "must be a mapping"),
    ],
)
def test_bad_config_raises_naming_the_key(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Config.from_dict(data)


def test_missing_or_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        Config.from_yaml(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("odometry: [1, 2")
    with pytest.raises(ConfigError, match="not valid YAML"):
        Config.from_yaml(bad)
