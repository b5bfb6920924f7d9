"""Config loading and validation, and the CLI's one-line errors (exit 2)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

from chpf.errors import ConfigError
from data_gen import cli
from data_gen.config import default_config, load_config

REPO = Path(__file__).resolve().parents[2]


def test_default_yaml_documents_every_key_with_its_default():
    data = yaml.safe_load((REPO / "configs" / "gen_default.yaml").read_text())
    assert data == default_config()
    assert load_config(REPO / "configs" / "gen_default.yaml") == default_config()


def test_overrides_and_sets(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("occlusion:\n  prob: 0.9\ncrop:\n  size: 32\n")
    cfg = load_config(p, ["pairs.hard_negative_share=0.5", "occlusion.fraction_range=[0.1, 0.2]"])
    assert cfg["occlusion"]["prob"] == 0.9 and cfg["crop"]["size"] == 32
    assert cfg["pairs"]["hard_negative_share"] == 0.5
    assert cfg["occlusion"]["fraction_range"] == [0.1, 0.2]
    assert cfg["noise"] == default_config()["noise"]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("occlusion:\n  probability: 0.5\n", "unknown key occlusion.probability"),
        ("colour:\n  prob: 0.5\n", "unknown section 'colour'"),
        ("occlusion:\n  prob: 1.5\n", "occlusion.prob: 1.5 is out of range"),
        ("crop:\n  size: 6.5\n", "crop.size: expected an integer"),
        ("occlusion:\n  fraction_range: [0.5, 0.1]\n", "min 0.5 > max 0.1"),
        ("pairs:\n  pos_rot_max_deg: 30\n", "must be below pairs.neg_min_angle_deg"),
        ("occlusion: [1, 2\n", "not valid YAML"),
    ],
)
def test_bad_configs(tmp_path, text, needle):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(p)
    msg = str(err.value)
    assert needle in msg and str(p) in msg and "\n" not in msg


def _run_cli(monkeypatch, capsys, argv):
    monkeypatch.setattr(sys, "argv", ["chpf-gen-data", *argv])
    with pytest.raises(SystemExit) as ex:
        cli.cli()
    return ex.value.code, capsys.readouterr().err


def test_cli_config_errors_exit_2_with_one_line(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    code, err = _run_cli(
        monkeypatch,
        capsys,
        ["pairs", "--object", "mug", "--out", str(out), "--n", "4", "--set", "noise.sigma=3"],
    )
    assert code == 2 and err.count("\n") == 1 and err.startswith("error: ")
    assert "unknown key noise.sigma" in err
    code, err = _run_cli(
        monkeypatch,
        capsys,
        ["ae", "--object", "mug", "--out", str(out), "--n", "4", "--set", "blur.prob=2"],
    )
    assert code == 2 and err.count("\n") == 1 and "out of range" in err
    code, err = _run_cli(
        monkeypatch, capsys, ["pairs", "--object", "teapot", "--out", str(out), "--n", "4"]
    )
    assert code == 2 and err.count("\n") == 1 and "teapot" in err
    code, err = _run_cli(
        monkeypatch,
        capsys,
        ["pairs", "--object", str(tmp_path / "x.ply"), "--out", str(out), "--n", "4"],
    )
    assert code == 2 and err.count("\n") == 1 and "x.ply" in err
    assert not out.exists()  # nothing written


def test_all_shipped_gen_configs_load():
    for path in sorted((REPO / "configs").glob("gen_*.yaml")):
        load_config(path)
