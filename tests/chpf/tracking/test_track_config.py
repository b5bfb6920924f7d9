"""Tracking options: YAML files, overrides, refusals, and the method registry they come from."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from chpf.config_schema import to_dict
from chpf.errors import ConfigError
from chpf.tracking.config import TrackConfig, make_config
from chpf.tracking.methods import METHODS, method_names

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = ROOT / "configs"


@pytest.mark.parametrize("name", ["track_default.yaml", "track_rgbd.yaml", "track_paper.yaml"])
def test_shipped_configs_load(name):
    cfg = make_config(CONFIGS / name)
    assert isinstance(cfg, TrackConfig) and cfg.filter.n_particles == 50


def test_default_yaml_matches_the_dataclass_defaults():
    assert make_config(CONFIGS / "track_default.yaml") == TrackConfig()
    # every key is written out, with its default
    assert yaml.safe_load((CONFIGS / "track_default.yaml").read_text()) == to_dict(TrackConfig())


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("track_*.yaml")), ids=lambda p: p.name)
def test_every_track_yaml_sets_only_known_keys(path):
    """The other files override a subset of the documented keys, in the same nested form."""
    data = yaml.safe_load(path.read_text())
    defaults = to_dict(TrackConfig())
    for section, keys in data.items():
        assert set(keys) <= set(defaults[section]), (path.name, section)
    assert make_config(data) == make_config(path)


def test_overrides_and_refusals(tmp_path):
    cfg = make_config(CONFIGS / "track_default.yaml", filter={"n_particles": 20}, srl={"beta": 0.5})
    assert cfg.filter.n_particles == 20 and cfg.srl.beta == 0.5
    assert cfg.candidates.z_range == (0.3, 2.0)
    assert make_config(CONFIGS / "track_default.yaml", ["srl.beta=0.5"]).srl.beta == 0.5
    assert make_config(None, ["chpf.sums=paper"]).chpf.sums == "paper"
    bad = tmp_path / "bad.yaml"
    bad.write_text("motion:\n  sigma_t: 0.01\nbogus: 3\n")
    with pytest.raises(ConfigError, match="bogus"):
        make_config(bad)
    bad.write_text("motion:\n  sigma_t: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml"):
        make_config(bad)
    for opts in (
        {"filter": {"n_particles": 0}},
        {"candidates": {"z_range": [2.0, 1.0]}},
        {"fixed": {"rate": 1.5}},
        {"chpf": {"c_mode": "maybe"}},
        {"chpf": {"sums": "everything"}},
        {"runtime": {"spin": "yes"}},
        {"e2e": {"sigma_t": [0.1, 0.1]}},
        {"candidates": {"box_uv_fraction": 0.0}},
    ):
        with pytest.raises(ConfigError):
            make_config(opts)
    with pytest.raises(ConfigError):
        make_config(tmp_path / "missing.yaml")


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("srl:\n  beta: 0\n", "srl.beta: 0.0 is out of range (0.0, inf)"),
        ("srl:\n  betta: 0.5\n", "unknown key srl.betta"),
        ("filter:\n  n_particles: 2.5\n", "filter.n_particles: expected an integer"),
        ("augmcl:\n  a_slow: 0.5\n", "augmcl.a_slow: needs 0 < a_slow < a_fast <= 1"),
        ("annealing:\n  betas: [0.5, 0.2, 1.0]\n", "annealing.betas: must rise"),
        ("srl_beta: 0.5\n", "srl_beta is now srl.beta"),
        ("anneal_decay: 0.5\n", "anneal_decay is now annealing.decay"),
    ],
)
def test_refusals_are_one_line_naming_the_file_and_the_key(tmp_path, text, needle):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        make_config(p)
    msg = str(err.value)
    assert needle in msg and str(p) in msg and "\n" not in msg


def test_set_errors_name_set():
    with pytest.raises(ConfigError, match=r"^--set: poserbpf.plus_fraction: 2.0 is out of range"):
        make_config(None, ["poserbpf.plus_fraction=2"])


def test_nested_dict_and_config_sources():
    cfg = make_config({"srl": {"beta": 0.4}, "motion": None})
    assert cfg.srl.beta == 0.4 and cfg.motion == TrackConfig().motion
    assert make_config(cfg, e2e={"rate": 0.5}).srl.beta == 0.4
    assert make_config(to_dict(cfg)) == cfg  # the plain dump reads back


def test_every_registered_method_with_options_has_its_section():
    for m in METHODS.values():
        if m.options is not None:
            assert isinstance(getattr(TrackConfig(), m.section), m.options)
    assert method_names(paper_only=True) == (
        "chpf",
        "srl",
        "augmcl",
        "annealing",
        "e2e",
        "poserbpf",
        "poserbpf++",
        "chrbpf",
    )
    assert METHODS["chrbpf"].also == ("chpf",)  # its alpha is CH-PF's rule, with its options


def test_readme_table_of_methods_matches_the_registry():
    text = (ROOT / "README.md").read_text()
    rows = re.findall(r"^\| `([^`]+)` \| (yes|no) \| `?([^|`]*)`? \| (.+?) \|$", text, re.M)
    table = {name: (paper, section, desc) for name, paper, section, desc in rows}
    expected = {
        m.name: ("yes" if m.paper else "no", m.section or "-", m.description)
        for m in METHODS.values()
    }
    assert table == expected
