"""chpf-train end to end on fabricated shards: checkpoints, resume, AE init, bad input."""

from __future__ import annotations

import csv
import dataclasses
import inspect
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from chpf.config_schema import to_dict
from chpf.errors import ConfigError
from export.pipeline import same_weights
from training.checkpoints import (
    checkpoint_info,
    load_autoencoder,
    load_classifier,
    state_sha256,
)
from training.cli import main, make_cli
from training.codebook import codebook_arrays, save_codebook
from training.evaluate import main as evaluate_main
from training.lit import CHLitModule
from training.model_config import ClassifierConfig

ROOT = Path(__file__).resolve().parents[2]
AE_CFG = str(ROOT / "configs" / "train_ae_tiny.yaml")
CH_CFG = str(ROOT / "configs" / "train_ch_tiny.yaml")


def _train_ae(ae_dir: Path, out: Path, *extra: str) -> Path:
    args = ["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]
    assert main([*args, "--trainer.default_root_dir", str(out), *extra]) == 0
    return out / "checkpoints" / "last.ckpt"


@pytest.fixture
def ae_ckpt(ae_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return _train_ae(ae_dir, tmp_path / "runs_ae")


def test_ae_trains_writes_checkpoints_and_resumes(ae_ckpt: Path, ae_dir: Path) -> None:
    out = ae_ckpt.parent.parent
    assert ae_ckpt.is_file() and list(out.glob("checkpoints/best-*.ckpt"))
    info = checkpoint_info(ae_ckpt, expect="ae")
    assert info["crop"]["size"] == 16 and info["model_config"]["embedding_dim"] == 16
    model, _ = load_autoencoder(ae_ckpt)
    assert model(torch.rand(2, 3, 16, 16))[1].shape == (2, 16)
    rows = list(csv.DictReader(open(next(out.glob("logs/version_*/metrics.csv")))))
    assert any(r.get("val/retrieval_median_deg") for r in rows)
    assert list(out.glob("tb/version_*/events.*"))
    assert torch.load(ae_ckpt, weights_only=False)["global_step"] == 4
    # resume from last.ckpt up to 6 steps
    _train_ae(ae_dir, out, "--ckpt_path", str(ae_ckpt), "--trainer.max_steps", "6")
    assert torch.load(ae_ckpt, weights_only=False)["global_step"] == 6


def test_ch_from_frozen_ae_encoder(
    ae_ckpt: Path, ae_dir: Path, pairs_dir: Path, tmp_path: Path, pattern_images
) -> None:
    out = tmp_path / "runs_ch"
    args = ["ch", "--config", CH_CFG, "--data.data_dir", str(pairs_dir)]
    args += ["--trainer.default_root_dir", str(out), "--model.init_from_ae", str(ae_ckpt)]
    assert main([*args, "--model.freeze_encoder", "true"]) == 0
    ch_ckpt = out / "checkpoints" / "last.ckpt"
    ch, info = load_classifier(ch_ckpt)
    assert info["shares_ae_encoder"] and ch.shares_ae_encoder and info["ae_encoder_sha256"]
    ae, _ = load_autoencoder(ae_ckpt)
    assert info["ae_encoder_sha256"] == state_sha256(ae.encoder)
    assert state_sha256(ch.obs_encoder) == state_sha256(ae.encoder)
    ch_state = ch.obs_encoder.state_dict()
    for k, a in ae.encoder.state_dict().items():
        assert torch.equal(a, ch_state[k]), k  # frozen: the observed branch IS the AE encoder
    # held-out evaluation prints and writes the figures
    imgs, R = pattern_images(50, 16, seed=9)
    save_codebook(tmp_path / "cb.npz", codebook_arrays(R, imgs))
    ev = ["--ae", str(ae_ckpt), "--ch", str(ch_ckpt), "--data", str(ae_dir)]
    ev += ["--pairs", str(pairs_dir), "--codebook", str(tmp_path / "cb.npz")]
    assert evaluate_main([*ev, "--json", str(tmp_path / "ev.json")]) == 0
    res = json.loads((tmp_path / "ev.json").read_text())
    assert res["ae"]["codebook_size"] == 50 and res["ae"]["n_samples"] == 64
    bands = res["ae"]["augmented_by_visibility"]
    assert sum(b["n"] for b in bands) == res["ae"]["n_samples"]
    # the bands split the samples: the mean error is theirs weighted, the median between theirs
    aug, full = res["ae"]["augmented"], [b for b in bands if b["n"]]
    mean = sum(b["n"] * b["mean_deg"] for b in full) / res["ae"]["n_samples"]
    assert aug["mean_deg"] == pytest.approx(mean, rel=1e-9)
    medians = [b["median_deg"] for b in full]
    assert min(medians) <= aug["median_deg"] <= max(medians)
    assert 0 <= res["pairs"]["classifier"]["auc"] <= 1 and res["pairs"]["n_pairs"] == 64
    hard_bands = res["pairs"]["classifier"]["auc_hard_by_visibility"]
    assert 0 <= res["pairs"]["classifier"]["auc_far"] <= 1
    c = res["pairs"]["classifier"]
    assert c["auc_hard_lo"] <= c["auc_hard"] <= c["auc_hard_hi"]
    assert sum(b["n_hard"] for b in hard_bands) <= res["pairs"]["n_hard_negatives"]
    assert "drop_occluded" in res["pairs"]["ae_cosine"]
    # wrong checkpoint types: one clear error each
    with pytest.raises(ConfigError, match="is a CH classifier checkpoint"):
        main(
            [
                "ch",
                "--config",
                CH_CFG,
                "--data.data_dir",
                str(pairs_dir),
                "--model.init_from_ae",
                str(ch_ckpt),
            ]
        )
    with pytest.raises(ConfigError, match="expected a CH classifier checkpoint"):
        main([*args[:7], "--ckpt_path", str(ae_ckpt)])


def test_refined_classifier_starts_as_the_autoencoders_encoder(ae_ckpt: Path) -> None:
    """With refine_stages the classifier loads the autoencoder's encoder around its new
    (zero-initialised) blocks, and so embeds crops exactly as the autoencoder does."""
    module = CHLitModule(ClassifierConfig(refine_stages=1), init_from_ae=str(ae_ckpt))
    module.init_encoders_from_ae(ae_ckpt)
    ae, _ = load_autoencoder(ae_ckpt)
    assert set(module.model.obs_encoder.refine) == {"1"}
    x = torch.rand(3, 3, ae.encoder.size, ae.encoder.size)
    # equal up to float rounding: the classifier runs channels_last, whose kernels round
    # differently on some CPUs (AVX2-only)
    torch.testing.assert_close(module.model.obs_encoder(x), ae.encoder(x), rtol=1e-5, atol=1e-6)
    # a frozen candidate branch stays the autoencoder's encoder, which the export then reuses
    cfg = ClassifierConfig(refine_stages=1)
    frozen = CHLitModule(cfg, init_from_ae=str(ae_ckpt), freeze_candidate=True)
    frozen.init_encoders_from_ae(ae_ckpt)
    assert set(frozen.model.obs_encoder.refine) == {"1"} and not frozen.model.cand_encoder.refine
    assert same_weights(frozen.model.cand_encoder, ae.encoder)


def test_crop_size_mismatch(ae_dir: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    enc = "{channels: [8, 16], kernel: 3, embedding_dim: 16, size: 32}"
    with pytest.raises(ConfigError, match="crop size 16 differs from the model config's size 32"):
        main(["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir), "--model.encoder", enc])


def test_console_error_is_one_line(tmp_path: Path) -> None:
    bogus = tmp_path / "x.ckpt"
    bogus.write_bytes(b"not a checkpoint")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    code = "from training.cli import cli; cli()"
    args = ["ch", "--config", CH_CFG, "--model.init_from_ae", str(bogus)]
    r = subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith(f"error: {bogus}: not a readable")
    assert "Traceback" not in r.stderr


def test_bf16_mixed_precision_trains_and_validates(
    ae_dir: Path, pairs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """bf16-mixed (what the default configs choose on CPUs with bf16 units): losses and
    validation metrics stay float32."""
    monkeypatch.chdir(tmp_path)
    bf16 = ("--trainer.precision", "bf16-mixed")
    ae_ckpt = _train_ae(ae_dir, tmp_path / "ae", *bf16)
    out = tmp_path / "ch"
    args = ["ch", "--config", CH_CFG, "--data.data_dir", str(pairs_dir), *bf16]
    assert (
        main([*args, "--trainer.default_root_dir", str(out), "--model.init_from_ae", str(ae_ckpt)])
        == 0
    )
    for run, key in ((tmp_path / "ae", "val/retrieval_median_deg"), (out, "val/auc")):
        rows = list(csv.DictReader(open(next(run.glob("logs/version_*/metrics.csv")))))
        values = [float(r[key]) for r in rows if r.get(key)]
        assert values and all(math.isfinite(v) for v in values), (run, key)
        state = torch.load(run / "checkpoints" / "last.ckpt", weights_only=False)["state_dict"]
        assert {v.dtype for v in state.values() if v.is_floating_point()} == {torch.float32}


@pytest.mark.parametrize(
    "kind, configs",
    [
        ("ae", ["train_ae.yaml"]),
        ("ae", ["train_ae.yaml", "train_ae_slim.yaml"]),
        ("ae", ["train_ae_poserbpf.yaml"]),
        ("ch", ["train_ch.yaml"]),
        ("ch", ["train_ch.yaml", "train_ch_frozen.yaml"]),
    ],
)
def test_shipped_configs_build_their_modules(
    kind: str, configs: list[str], ae_ckpt: Path, tmp_path: Path
) -> None:
    """Each shipped config (and the documented combinations) builds its LightningModule through
    chpf-train's parser, with the required paths given as on the README's command lines."""
    args = [a for name in configs for a in ("--config", str(ROOT / "configs" / name))]
    args += ["--trainer.default_root_dir", str(tmp_path / "runs")]
    if kind == "ch":
        args += ["--model.init_from_ae", str(ae_ckpt)]
        args += ["--model.candidate_codebook", str(tmp_path / "cb.npz")]  # read at train start
    cli = make_cli(kind, args)
    module, model = cli.model, cli.config["model"]
    if kind == "ae":
        assert module.model.config.size in (64, 128)
        return
    frozen = module._frozen_branch()
    if model.get("freeze_encoder") or model.get("freeze_candidate"):
        assert frozen is not None and not any(p.requires_grad for p in frozen.parameters())
    else:  # the default: one trained encoder serves both branches
        assert frozen is None and module.model.obs_encoder is module.model.cand_encoder
        assert all(p.requires_grad for p in module.model.parameters())


@pytest.mark.parametrize("kind", ["ae", "ch"])
def test_default_train_yaml_documents_every_model_key(kind: str, tmp_path: Path) -> None:
    """configs/train_{kind}.yaml names every model argument and every key of its typed configs,
    and chpf-train reads back exactly what it says; the classifier section holds the
    ClassifierConfig defaults but the refine blocks (its encoder is the autoencoder's at run
    time)."""
    from training.lit import AELitModule, CHLitModule

    path = ROOT / "configs" / f"train_{kind}.yaml"
    written = yaml.safe_load(path.read_text())["model"]
    module_class = AELitModule if kind == "ae" else CHLitModule
    params = inspect.signature(module_class).parameters
    assert set(written) == set(params)
    for name, p in params.items():
        if dataclasses.is_dataclass(p.default):
            assert set(written[name]) == set(to_dict(p.default)), name
    init = [] if kind == "ae" else ["--model.init_from_ae", "null", "--model.extra_pairs", "0"]
    root = ["--trainer.default_root_dir", str(tmp_path)]
    parsed = make_cli(kind, ["--config", str(path), *root, *init]).config["model"].as_dict()
    if kind == "ch":
        # the defaults are the networks of checkpoints older than a key; the YAML adds blocks
        blocks = ClassifierConfig(refine_stages=2, refine_reduction=4)
        assert written["classifier"] == to_dict(blocks)
        parsed["init_from_ae"], parsed["extra_pairs"] = written["init_from_ae"], 32
    assert json.loads(json.dumps(parsed)) == written


def test_unknown_and_out_of_range_model_keys_are_refused(
    ae_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """LightningCLI refuses unknown keys of the typed model configs; out-of-range values are
    one ConfigError line naming the dotted key."""
    args = ["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]
    args += ["--trainer.default_root_dir", str(tmp_path)]
    with pytest.raises(SystemExit):
        main([*args, "--model.encoder.kernal", "3"])
    assert "--model.encoder.kernal" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("model:\n  encoder: {channels: [8, 16], bogus: 1}\n")
    with pytest.raises(SystemExit):
        main([*args, "--config", str(bad)])
    assert "bogus" in capsys.readouterr().err
    with pytest.raises(ConfigError, match=r"^chpf-train ae: model\.encoder\.kernel: must be odd"):
        main([*args, "--model.encoder.kernel", "4"])
    with pytest.raises(ConfigError, match=r"model\.encoder\.channels: 0 is out of range"):
        main([*args, "--model.encoder.channels", "[8, 0]"])


def test_lr_schedule_by_time_ends_the_decay_at_max_time(ae_dir: Path, tmp_path: Path) -> None:
    """A run stopped by max_time long before max_steps (chpf-make-bundle's trainings) still
    ends at lr * min_lr_ratio with lr_schedule_by_time; without it the lr stays near its peak."""
    lrs = {}
    for by_time in ("true", "false"):
        out = tmp_path / f"run_{by_time}"
        last = _train_ae(
            ae_dir, out, "--trainer.max_steps", "100000", "--trainer.max_time", "00:00:00:03",
            "--trainer.val_check_interval", "100000", "--model.warmup_steps", "0",
            "--model.lr_schedule_by_time", by_time,
        )  # fmt: skip
        ck = torch.load(last, weights_only=False)
        assert 1 < ck["global_step"] < 100000  # stopped by max_time
        lrs[by_time] = ck["lr_schedulers"][0]["_last_lr"][0]
    lr = 3e-3  # configs/train_ae_tiny.yaml's; min_lr_ratio 0.02 by default
    assert lrs["true"] == pytest.approx(0.02 * lr)  # decayed to lr * min_lr_ratio
    assert lrs["false"] > 0.9 * lr


def test_warmup_cosine_follows_the_earlier_limit() -> None:
    import time

    from lightning.pytorch.callbacks import Timer
    from lightning.pytorch.trainer.states import RunningStage

    from training.lit import _warmup_cosine, time_progress

    assert _warmup_cosine(50, 100, 10_000, 0.02) == pytest.approx(0.51)  # warm-up: steps
    assert _warmup_cosine(10, 100, 10_000, 0.02, 0.05) == pytest.approx(0.5)  # or 10 % of time
    assert _warmup_cosine(50, 100, 10_000, 0.02, 0.01) == pytest.approx(0.51)  # what's first
    assert _warmup_cosine(50, 100, 10_000, 0.02, 1.0) == pytest.approx(0.02)  # few steps
    assert _warmup_cosine(200, 100, 10_000, 0.02) > 0.99  # steps only: early
    assert _warmup_cosine(200, 100, 10_000, 0.02, 1.0) == pytest.approx(0.02)  # time is up
    assert _warmup_cosine(200, 100, 10_000, 0.02, 0.5) == pytest.approx(0.51)
    assert _warmup_cosine(10_000, 100, 10_000, 0.02, 0.1) == pytest.approx(0.02)  # steps up
    assert _warmup_cosine(200, 100, math.inf, 0.02, 0.5) == pytest.approx(0.51)  # no max_steps
    assert _warmup_cosine(200, 100, math.inf, 0.02) == 1.0
    timer = Timer(duration={"seconds": 100})
    assert time_progress([]) is None and time_progress([Timer(duration=None)]) is None
    timer._start_time[RunningStage.TRAINING] = time.monotonic() - 25
    assert time_progress([timer]) == pytest.approx(0.25, abs=0.01)
