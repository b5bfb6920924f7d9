"""Tracking options: YAML files, overrides, refusals."""

from __future__ import annotations

from pathlib import Path

import pytest

from chpf.errors import ConfigError
from chpf.tracking.config import TrackConfig, make_config

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


@pytest.mark.parametrize("name", ["track_default.yaml", "track_rgbd.yaml", "track_informed.yaml"])
def test_shipped_configs_load(name):
    cfg = make_config(CONFIGS / name)
    assert isinstance(cfg, TrackConfig) and cfg.n_particles == 50


def test_default_yaml_matches_the_dataclass_defaults():
    assert make_config(CONFIGS / "track_default.yaml") == TrackConfig()


def test_overrides_and_refusals(tmp_path):
    cfg = make_config(CONFIGS / "track_default.yaml", n_particles=20, srl_beta=0.5)
    assert cfg.n_particles == 20 and cfg.srl_beta == 0.5 and cfg.z_range == (0.3, 2.0)
    bad = tmp_path / "bad.yaml"
    bad.write_text("sigma_t: 0.01\nbogus: 3\n")
    with pytest.raises(ConfigError, match="bogus"):
        make_config(bad)
    bad.write_text("sigma_t: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml"):
        make_config(bad)
    for opts in (
        {"n_particles": 0},
        {"z_range": [2.0, 1.0]},
        {"fixed_rate": 1.5},
        {"c_mode": "maybe"},
        {"spin": "yes"},
        {"e2e_sigma_t": [0.1, 0.1]},
        {"box_uv_fraction": 0.0},
    ):
        with pytest.raises(ConfigError):
            make_config(opts)
    with pytest.raises(ConfigError):
        make_config(tmp_path / "missing.yaml")
