"""The autoencoder validates retrieval against a rendered codebook of uniform orientations
(``val_codebook_size``), cached in the run folder and rebuilt when its settings differ."""

from __future__ import annotations

import csv
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

from data_gen.shards import read_manifest
from training.cli import main
from training.lit import ensure_val_codebook, val_codebook_cache

ROOT = Path(__file__).resolve().parents[2]
AE_CFG = str(ROOT / "configs" / "train_ae_tiny.yaml")


def _median(out: Path) -> list[float]:
    rows = list(csv.DictReader(open(next(out.glob("logs/version_*/metrics.csv")))))
    return [float(r["val/retrieval_median_deg"]) for r in rows if r.get("val/retrieval_median_deg")]


def test_tiny_run_validates_against_the_rendered_codebook(
    ae_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CHPF_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    args = ["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]
    assert main([*args, "--trainer.default_root_dir", str(out)]) == 0
    path, key = val_codebook_cache(out, read_manifest(ae_dir), 64)
    assert path.is_file()
    with np.load(path) as z:
        assert z["rotations"].shape == (64, 3, 3) and z["crops"].shape == (64, 16, 16, 3)
    # an untrained model against 64 uniform views of the box (the fixture's images are
    # patterns): far from the ~0 of the old proxy (each crop finding its own target)
    assert min(_median(out)) > 10.0
    # the proxy, for comparison: val_codebook_size 0
    proxy = tmp_path / "proxy"
    assert (
        main([*args, "--trainer.default_root_dir", str(proxy), "--model.val_codebook_size", "0"])
        == 0
    )
    assert not (proxy / "val_codebook").exists()
    assert min(_median(proxy)) < min(_median(out))
    # reused: a second run in the same folder does not render again
    mtime = os.stat(path).st_mtime_ns
    assert ensure_val_codebook(path, key, ae_dir, 64) is False
    assert os.stat(path).st_mtime_ns == mtime


def test_cache_of_other_settings_is_rebuilt(ae_dir: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("CHPF_CACHE", str(tmp_path / "cache"))
    man = read_manifest(ae_dir)
    path, key = val_codebook_cache(tmp_path, man, 8)
    other, other_key = val_codebook_cache(tmp_path, {**man, "object_fingerprint": "f" * 40}, 8)
    assert other_key != key and other != path
    assert val_codebook_cache(tmp_path, man, 16)[1] != key
    assert ensure_val_codebook(path, key, ae_dir, 8) is True
    assert ensure_val_codebook(path, key, ae_dir, 8) is False
    # a file at that path holding a codebook of other settings: refused as it is, rebuilt
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["cache_key"] = np.asarray(["0" * 16])
    np.savez(path, **arrays)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        assert ensure_val_codebook(path, key, ae_dir, 8) is True
    assert any("other settings" in str(w.message) for w in got)
    with np.load(path) as z:
        assert str(z["cache_key"].reshape(-1)[0]) == key and len(z["rotations"]) == 8


def test_unrenderable_object_is_one_line(ae_dir: Path, tmp_path: Path, monkeypatch) -> None:
    """A data folder whose object cannot be found: DatasetError naming the way out."""
    import json

    from chpf.errors import DatasetError

    man = json.loads((ae_dir / "manifest.json").read_text())
    man["object"] = "gone.ply"
    (ae_dir / "manifest.json").write_text(json.dumps(man))
    monkeypatch.chdir(tmp_path)
    args = ["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]
    with pytest.raises(DatasetError, match=r"--model.val_codebook_size 0\)$"):
        main([*args, "--trainer.default_root_dir", str(tmp_path / "run")])


def test_validation_crops_cut_with_jitter_are_warned_about(
    ae_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, shard_writer
) -> None:
    """Crops cut with crop jitter that their targets follow (the generator's default) make the
    retrieval error read the shift: on the duck's default data 110 deg all through training,
    where crops without jitter read 13. Training says so, and not with a val_dir without it."""
    import json

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CHPF_CACHE", str(tmp_path / "cache"))
    args = ["ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]

    def warned(extra: list[str], root: str) -> bool:
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            assert main([*args, *extra, "--trainer.default_root_dir", str(tmp_path / root)]) == 0
        return any("--data.val_dir" in str(w.message) for w in got)

    assert warned([], "jittered")
    clean = shard_writer(tmp_path / "val", "ae", 32)
    man = json.loads((clean / "manifest.json").read_text())
    man["config"] = {"crop_jitter": {"xy_sigma": 0.0, "z_sigma": 0.0, "ae_target": "follow"}}
    (clean / "manifest.json").write_text(json.dumps(man))
    assert not warned(["--data.val_dir", str(clean)], "clean")
