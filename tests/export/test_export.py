"""chpf-export end to end on tiny random models: ONNX parity, bundle files, refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from chpf.bundle import Bundle
from chpf.config_schema import load
from chpf.crops import CropSpec
from chpf.errors import BundleError, ConfigError
from chpf.objects import get_object
from export import cli as export_cli
from export import onnx_export
from export.config import ExportConfig
from export.pipeline import export_bundle
from training.lit import AELitModule, CHLitModule
from training.model_config import ClassifierConfig, EncoderConfig, HeadConfig
from training.models import HeadProbability, NormalizedEmbedder

S, K, OBJ = 32, 64, "box"
TINY = EncoderConfig(channels=(8, 16), kernel=3, embedding_dim=16, size=S)


def _save(module, path: Path, data_info: dict) -> Path:
    """Save a checkpoint the way Lightning + our modules' on_save_checkpoint do."""
    module.data_info = dict(data_info)
    ckpt = {
        "state_dict": module.state_dict(),
        "hyper_parameters": dict(module.hparams),
        "epoch": 0,
        "global_step": 0,
    }
    module.on_save_checkpoint(ckpt)
    torch.save(ckpt, path)
    return path


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("export")
    torch.manual_seed(0)
    obj = get_object(OBJ)
    spec = CropSpec.for_object(obj.diameter, size=S)
    info = {"crop": spec.to_dict(), "object": OBJ, "object_fingerprint": None}
    ae = AELitModule(encoder=TINY)
    ae_ckpt = _save(ae, root / "ae.ckpt", info)
    head = HeadConfig(hidden=(32, 16))
    ch = CHLitModule(classifier=ClassifierConfig(head=head), init_from_ae=str(ae_ckpt))
    ch.setup("fit")  # copies the AE encoder in; perturb so that the CH encoder differs
    with torch.no_grad():
        for p in ch.model.obs_encoder.parameters():
            p.add_(0.05 * torch.randn_like(p))
    ch_ckpt = _save(ch, root / "ch.ckpt", info)
    chs = CHLitModule(init_from_ae=str(ae_ckpt), freeze_encoder=True)
    chs.setup("fit")
    chs_ckpt = _save(chs, root / "ch_shared.ckpt", info)
    cfg = ExportConfig(codebook_size=K, parity_samples=16, cache_dir=str(root / "cache"))
    out = root / "bundles" / OBJ
    res = export_bundle(ae_ckpt, ch_ckpt, OBJ, out, cfg, progress=False)
    return {
        "root": root,
        "ae": ae.model.eval(),
        "ch": ch.model.eval(),
        "ae_ckpt": ae_ckpt,
        "ch_ckpt": ch_ckpt,
        "chs_ckpt": chs_ckpt,
        "cfg": cfg,
        "out": out,
        "res": res,
        "spec": spec,
    }


def _pool_crops(env: dict, n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    from data_gen.pool import codebook_pool

    _, views = codebook_pool(get_object(OBJ), env["spec"], K, env["cfg"].cache_dir, progress=False)
    idx = np.arange(0, K, K // n)[:n]
    return np.ascontiguousarray(views.rgb[idx]), idx


def _torch_embed(encoder, crops: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return NormalizedEmbedder(encoder).eval()(torch.from_numpy(crops)).numpy()


def test_bundle_reproduces_torch(env):
    b = Bundle.load(env["out"], threads=1)
    crops, idx = _pool_crops(env)
    ae, ch = env["ae"], env["ch"]
    emb = b.embed(crops)
    assert np.abs(emb - _torch_embed(ae.encoder, crops)).max() <= 1e-4
    obs = _check_classifier(b, ch, crops, idx)
    assert np.abs(obs - emb).max() > 1e-3  # a separate classifier encoder
    assert np.abs(b.ae_codebook[idx] - emb).max() <= 1e-4
    np.testing.assert_array_equal(b.nearest(b.grid.rotations[idx]), idx)


def _check_classifier(b: Bundle, ch, crops: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The bundle's classifier calls equal torch's on pool crops (codebook entry idx = crop idx);
    returns the observed-branch embeddings."""
    obs = b.ch_embed(crops)
    assert obs.shape == (len(idx), b.embedding_dim)
    assert np.abs(obs - _torch_embed(ch.obs_encoder, crops)).max() <= 1e-4
    assert np.abs(b.ch_codebook[idx] - _torch_embed(ch.cand_encoder, crops)).max() <= 1e-4
    cand_idx = np.roll(idx, 3)
    p = b.p_misaligned(obs, cand_idx)
    with torch.no_grad():
        want = HeadProbability(ch.head).eval()(
            torch.from_numpy(obs), torch.from_numpy(b.ch_codebook[cand_idx])
        )
    assert p.shape == (len(idx),)
    assert np.abs(p - want.numpy()).max() <= 1e-4
    # torch end to end (uint8 crops through the classifier's own preprocessing)
    with torch.no_grad():
        pre = ch.embed_obs(torch.from_numpy(crops).permute(0, 3, 1, 2).float() / 255.0)
    assert np.abs(pre.numpy() - obs).max() <= 1e-4
    return obs


def test_frozen_candidate_bundle_reuses_the_autoencoder_codebook(env, tmp_path):
    """A classifier whose candidate branch is the frozen AE encoder: its own observed encoder
    is exported, its candidate embeddings are the AE codebook's (not stored twice)."""
    torch.manual_seed(1)
    ch = CHLitModule(init_from_ae=str(env["ae_ckpt"]), freeze_candidate=True)
    ch.setup("fit")
    with torch.no_grad():
        for p in ch.model.obs_encoder.parameters():
            p.add_(0.05 * torch.randn_like(p))
    info = {"crop": env["spec"].to_dict(), "object": OBJ, "object_fingerprint": None}
    ckpt = _save(ch, tmp_path / "ch_frozen_cand.ckpt", info)
    out = tmp_path / "frozen_cand"
    export_bundle(env["ae_ckpt"], ckpt, OBJ, out, env["cfg"], progress=False)
    with np.load(out / "codebook.npz") as z:
        assert "ch_embeddings" not in z.files
    m = json.loads((out / "manifest.json").read_text())
    assert m["ch_shares_ae_encoder"] is False and m["files"]["ch_obs_encoder"]
    b = Bundle.load(out, threads=1)
    np.testing.assert_array_equal(b.ch_codebook, b.ae_codebook)
    crops, idx = _pool_crops(env)
    obs = _check_classifier(b, ch.model.eval(), crops, idx)
    assert np.abs(obs - b.embed(crops)).max() > 1e-3


def test_obj_id_is_set_by_the_config_or_the_flag(env, tmp_path):
    """--obj-id (ExportConfig.obj_id) overrides the object's own obj_id (the box's 2) in the
    manifest, so that the bundle matches a dataset that numbers the object otherwise."""
    cfg = load(ExportConfig, data={"obj_id": 5}, base=env["cfg"])
    out = tmp_path / "as5"
    export_bundle(env["ae_ckpt"], env["chs_ckpt"], OBJ, out, cfg, progress=False)
    assert json.loads((out / "manifest.json").read_text())["object"]["obj_id"] == 5
    assert Bundle.load(out, threads=1).obj_info.obj_id == 5
    assert (
        export_cli.build_parser()
        .parse_args(["--ae", "a", "--ch", "c", "--object", OBJ, "--out", "o", "--obj-id", "5"])
        .obj_id
        == 5
    )


def test_manifest_and_files(env):
    out = env["out"]
    m = json.loads((out / "manifest.json").read_text())
    assert m["format_version"] == 1
    assert m["object"]["name"] == OBJ and m["object"]["obj_id"] == 2
    assert m["object"]["diameter"] == pytest.approx(get_object(OBJ).diameter)
    assert m["crop"] == env["spec"].to_dict()
    assert m["embedding_dim"] == TINY.embedding_dim and m["codebook_size"] == K
    assert m["ch_shares_ae_encoder"] is False
    assert m["files"]["ch_obs_encoder"] == "ch_encoder.onnx"
    assert set(m["sha256"]) == {f for f in m["files"].values() if f}
    assert m["training"]["ae"]["model_type"] == "ae"
    assert m["training"]["ch"]["model_config"]["head"]["hidden"] == [32, 16]
    assert max(m["parity"]["max_abs_diff"].values()) <= 1e-4
    assert m["created_by"].startswith("chpf-export ")
    b = Bundle.load(out)
    d = b.codebook_depth(np.arange(K))
    assert d.shape == (K, S // 2, S // 2)
    assert (d > 0).any() and np.all((d == 0) | (np.abs(d - b.spec.render_distance) < 0.3))
    # no temp folders left next to the bundle
    assert sorted(p.name for p in out.parent.iterdir()) == [OBJ]


def test_shared_encoder_cli(env, capsys):
    out = env["root"] / "shared"
    code = export_cli.main(
        [
            "--ae", str(env["ae_ckpt"]), "--ch", str(env["chs_ckpt"]), "--object", OBJ,
            "--out", str(out), "--codebook-size", str(K), "--cache-dir", env["cfg"].cache_dir,
            "--threads", "1", "--quiet",
        ]
    )  # fmt: skip
    assert code == 0
    assert "wrote" in capsys.readouterr().out
    m = json.loads((out / "manifest.json").read_text())
    assert m["ch_shares_ae_encoder"] is True and m["files"]["ch_obs_encoder"] is None
    assert not (out / "ch_encoder.onnx").exists()
    b = Bundle.load(out)
    crops, _ = _pool_crops(env, 8)
    np.testing.assert_array_equal(b.ch_embed(crops), b.embed(crops))
    np.testing.assert_array_equal(b.ch_codebook, b.ae_codebook)
    # same AE -> the same AE codebook as the unshared bundle
    np.testing.assert_allclose(b.ae_codebook, Bundle.load(env["out"]).ae_codebook, atol=1e-6)


def test_wrong_checkpoint_type(env, capsys):
    argv = [
        "--ae", str(env["ch_ckpt"]), "--ch", str(env["ch_ckpt"]), "--object", OBJ,
        "--out", str(env["root"] / "wrong"), "--codebook-size", str(K),
    ]  # fmt: skip
    with pytest.raises(ConfigError, match=r"ch\.ckpt: is a CH classifier checkpoint"):
        export_cli.main(argv)
    with pytest.raises(SystemExit) as exit_info:
        _run_cli(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "expected an autoencoder" in err
    assert not (env["root"] / "wrong").exists()


def _run_cli(argv: list[str]) -> None:
    import sys

    old = sys.argv
    sys.argv = ["chpf-export", *argv]
    try:
        export_cli.cli()
    finally:
        sys.argv = old


def test_out_with_other_object_refused(env):
    cfg = env["cfg"]
    with pytest.raises(BundleError, match=r"holds a bundle of object 'box', not 'can'"):
        export_bundle(env["ae_ckpt"], env["ch_ckpt"], "can", env["out"], cfg, progress=False)
    assert json.loads((env["out"] / "manifest.json").read_text())["object"]["name"] == OBJ


def test_trained_object_mismatch_refused(env):
    with pytest.raises(BundleError, match="trained on object 'box', not 'mug'"):
        export_bundle(
            env["ae_ckpt"], env["ch_ckpt"], "mug", env["root"] / "mug", env["cfg"], True, False
        )
    assert not (env["root"] / "mug").exists()


def test_non_bundle_folder_refused(env):
    junk = env["root"] / "junk"
    junk.mkdir()
    (junk / "notes.txt").write_text("mine")
    with pytest.raises(BundleError, match="holds no bundle"):
        export_bundle(env["ae_ckpt"], env["ch_ckpt"], OBJ, junk, env["cfg"], True, False)
    assert (junk / "notes.txt").read_text() == "mine"


def test_overwrite_replaces_other_object(env, tmp_path):
    """A bundle of another object is replaced with --overwrite (same checkpoints, renamed)."""
    out = tmp_path / "b"
    out.mkdir()
    (out / "manifest.json").write_text(json.dumps({"object": {"name": "can"}}))
    (out / "old.bin").write_bytes(b"x")
    with pytest.raises(BundleError, match="--overwrite"):
        export_bundle(env["ae_ckpt"], env["ch_ckpt"], OBJ, out, env["cfg"], False, False)
    export_bundle(env["ae_ckpt"], env["ch_ckpt"], OBJ, out, env["cfg"], True, False)
    assert not (out / "old.bin").exists()
    assert Bundle.load(out).obj_info.name == OBJ
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_parity_failure_writes_nothing(env, tmp_path, monkeypatch):
    monkeypatch.setattr(onnx_export, "parity_error", lambda *a, **k: 1.0)
    out = tmp_path / "b"
    with pytest.raises(BundleError, match=r"differs from torch by 1 > 0\.0001"):
        export_bundle(env["ae_ckpt"], env["ch_ckpt"], OBJ, out, env["cfg"], False, False)
    assert list(tmp_path.iterdir()) == []


def test_export_config_rejects_unknown_keys(tmp_path):
    p = tmp_path / "export.yaml"
    p.write_text("codebook_size: 100\nbogus: 1\n")
    with pytest.raises(ConfigError, match="unknown key bogus"):
        ExportConfig.from_yaml(p)
    p.write_text("export:\n  codebook_size: 100\n")
    assert ExportConfig.from_yaml(p).codebook_size == 100
    assert ExportConfig.from_yaml(p, ["threads=3"]).threads == 3
    p.write_text("parity_samples: 1\n")
    with pytest.raises(ConfigError, match=r"export\.yaml: parity_samples: 1 is out of range"):
        ExportConfig.from_yaml(p)
    p.write_text("unit: km\n")
    with pytest.raises(ConfigError, match="unit: expected one of m, cm, mm"):
        ExportConfig.from_yaml(p)


def test_export_default_yaml_documents_every_key_with_its_default():
    path = Path(__file__).resolve().parents[2] / "configs" / "export_default.yaml"
    assert yaml.safe_load(path.read_text()) == ExportConfig().to_dict()
    assert ExportConfig.from_yaml(path) == ExportConfig()


def test_mesh_in_millimetres_given_as_metres_is_refused(env, tmp_path, capsys):
    """The box written in mm and exported with --unit m (a 319.7 m object with obj_id 0) exits 2
    in one line naming --unit mm, nothing written; --allow-size passes the size check (and
    meets the next one: the checkpoints were trained on 'box')."""
    mesh = get_object(OBJ).mesh.copy()
    mesh.apply_scale(1000.0)
    path = tmp_path / "box_mm.ply"
    mesh.export(path)
    out = tmp_path / "b"
    argv = ["--ae", str(env["ae_ckpt"]), "--ch", str(env["chs_ckpt"]), "--object", str(path)]
    argv += ["--unit", "m", "--out", str(out), "--quiet"]
    with pytest.raises(SystemExit) as exit_info:
        _run_cli(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1, err
    assert "diameter 319.7 m" in err[0] and "--unit mm" in err[0]
    assert not out.exists()
    with pytest.raises(SystemExit):
        _run_cli([*argv, "--allow-size"])
    assert "trained on object 'box', not 'box_mm'" in capsys.readouterr().err
