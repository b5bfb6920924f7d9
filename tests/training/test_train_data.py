"""Shard data modules: splits, sampler, batches, bad folders (one-line errors)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from chpf.errors import ConfigError, DatasetError
from training.data import (
    AEDataModule,
    PairDataModule,
    ShardBlockSampler,
    split_indices,
)


def test_split_by_shard_and_by_index() -> None:
    tr, va = split_indices([10, 10, 10, 10], 0.25, "shard", seed=3)
    assert va.size == 10 and np.intersect1d(tr, va).size == 0
    assert np.union1d(tr, va).tolist() == list(range(40))
    assert np.unique(va // 10).size == 1  # one whole shard held out
    _, va2 = split_indices([10, 10, 10, 10], 0.25, "shard", seed=3)
    assert np.array_equal(va, va2)
    tr, va = split_indices([40], 0.25, "shard", seed=0)  # one shard: falls back to samples
    assert va.size == 10 and tr.size == 30
    with pytest.raises(ConfigError):
        split_indices([10], 1.5, "index", 0)


def test_block_sampler_covers_every_sample_shard_by_shard() -> None:
    shard_of = np.repeat(np.arange(5), 8)
    s = ShardBlockSampler(shard_of, seed=1, shards_in_flight=1)
    e0, e1 = list(s), list(s)
    assert sorted(e0) == list(range(40)) and sorted(e1) == list(range(40))
    assert e0 != e1  # new order each epoch
    blocks = shard_of[np.array(e0)].reshape(5, 8)
    assert all(np.unique(b).size == 1 for b in blocks)  # one shard at a time


def test_ae_datamodule_batches(ae_dir: Path) -> None:
    dm = AEDataModule(str(ae_dir), batch_size=8, val_fraction=0.25)
    dm.setup("fit")
    assert len(dm.train_set) == 48 and len(dm.val_set) == 16
    batch = next(iter(dm.train_dataloader()))
    assert batch["input_rgb"].shape == (8, 16, 16, 3) and batch["input_rgb"].dtype == torch.uint8
    assert batch["target_mask"].dtype == torch.uint8 and batch["R_allo"].shape == (8, 3, 3)
    dm.check_crop_size(16)
    with pytest.raises(ConfigError, match=r"crop size 16 differs .* size 32"):
        dm.check_crop_size(32)


def test_pairs_datamodule_with_separate_val_dir(pairs_dir: Path, shard_writer, tmp_path) -> None:
    val = shard_writer(tmp_path / "val", "pairs", 20, per_shard=8, seed=5)
    dm = PairDataModule(str(pairs_dir), val_dir=str(val), batch_size=4)
    dm.setup("fit")
    assert len(dm.train_set) == 64 and len(dm.val_set) == 20
    batch = next(iter(dm.val_dataloader()))
    assert set(batch) >= {"obs_rgb", "cand_rgb", "aligned", "angle_deg", "visib_fract"}


def test_wrong_kind_and_missing_folder(ae_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="kind is 'ae', expected 'pairs'"):
        PairDataModule(str(ae_dir)).setup("fit")
    with pytest.raises(DatasetError, match=r"no manifest\.json"):
        AEDataModule(str(tmp_path / "nowhere")).setup("fit")


def test_empty_and_corrupt_shards_name_the_file(ae_dir: Path) -> None:
    shard = ae_dir / "shard_00001.npz"
    shard.write_bytes(b"")
    with pytest.raises(DatasetError, match=r"shard_00001\.npz: empty shard"):
        AEDataModule(str(ae_dir)).setup("fit")
    shard.write_bytes(b"garbage, not a zip file" * 10)
    with pytest.raises(DatasetError, match=r"shard_00001\.npz: corrupt shard"):
        AEDataModule(str(ae_dir)).setup("fit")
    man = json.loads((ae_dir / "manifest.json").read_text())
    man["shards"][1]["n"] = 0
    (ae_dir / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(DatasetError, match=r"shard_00001\.npz: empty shard"):
        AEDataModule(str(ae_dir)).setup("fit")
