"""LightningDataModules over ``chpf-gen-data`` shards (``data_gen.shards.ShardDataset``).

Samples are read shard by shard: the training sampler shuffles the order of the shards and the
samples inside a few shards at a time, so a small LRU cache of loaded shards serves almost every
read. Batches are dicts of CPU tensors with the shard arrays' dtypes (RGB stays uint8 (B,S,S,3));
the LightningModules convert them.
"""

from __future__ import annotations

import os
import zipfile
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from chpf.errors import ChpfError, ConfigError, DatasetError

AE_KEYS = ("input_rgb", "target_rgb", "target_mask", "R_allo", "visib_fract")
PAIR_KEYS = (
    "obs_rgb",
    "cand_rgb",
    "aligned",
    "obs_R_allo",
    "cand_R_allo",
    "angle_deg",
    "visib_fract",
    "depth_ratio",
)
REQUIRED_KEYS = {"ae": AE_KEYS, "pairs": PAIR_KEYS}


def open_shards(data_dir: str | os.PathLike, kind: str, mmap: bool = False) -> Any:
    """Open a shard folder with ``data_gen.shards.ShardDataset`` and check its kind and files.

    Raises DatasetError (one line naming the file) if the folder, the manifest or a shard file is
    missing, empty or not a readable npz with the arrays of ``kind`` ("ae" or "pairs").
    """
    from data_gen.shards import ShardDataset

    data_dir = Path(data_dir)
    if not (data_dir / "manifest.json").is_file():
        raise DatasetError(f"{data_dir}: no manifest.json (not a chpf-gen-data shard folder)")
    try:
        reader = ShardDataset(data_dir, mmap=mmap)
    except ChpfError:
        raise
    except Exception as err:
        raise DatasetError(
            f"{data_dir}/manifest.json: unreadable ({type(err).__name__}: {err})"
        ) from None
    manifest = reader.manifest
    if manifest.get("kind") != kind:
        raise DatasetError(
            f"{data_dir}/manifest.json: data kind is '{manifest.get('kind')}', expected '{kind}'"
        )
    shards = manifest.get("shards") or []
    if not shards or sum(int(s.get("n", 0)) for s in shards) == 0:
        raise DatasetError(f"{data_dir}/manifest.json: the data set has no samples")
    for s in shards:
        _check_shard_file(data_dir / s["file"], int(s.get("n", 0)), REQUIRED_KEYS[kind])
    return reader


def _check_shard_file(path: Path, n: int, keys: Sequence[str]) -> None:
    """Cheap check (zip directory only) that a shard exists, is non-empty and holds ``keys``."""
    if not path.is_file():
        raise DatasetError(f"{path}: shard file listed in manifest.json is missing")
    if n <= 0 or path.stat().st_size == 0:
        raise DatasetError(f"{path}: empty shard")
    try:
        with zipfile.ZipFile(path) as zf:
            names = {name.removesuffix(".npy") for name in zf.namelist()}
    except (zipfile.BadZipFile, OSError) as err:
        raise DatasetError(f"{path}: corrupt shard ({err})") from None
    missing = [k for k in keys if k not in names]
    if missing:
        raise DatasetError(f"{path}: shard lacks arrays {missing}")


def shard_crop_size(reader: Any) -> int:
    """Crop size S of a shard folder's manifest (DatasetError if absent)."""
    try:
        return int(reader.manifest["crop"]["size"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError("manifest.json: no crop size (crop.size)") from None


def check_crop_size(reader: Any, data_dir: str | os.PathLike, model_size: int) -> None:
    """ConfigError (one line) if the shards' crop size differs from the model config's size."""
    size = shard_crop_size(reader)
    if size != int(model_size):
        raise ConfigError(
            f"{Path(data_dir) / 'manifest.json'}: crop size {size} differs from the model "
            f"config's size {int(model_size)}"
        )


class ShardSamples(Dataset):
    """Torch Dataset over a subset of a shard folder's samples with an LRU cache of shards.

    ``indices`` are global sample indices (shard order). ``__getitem__(i)`` returns a dict of
    numpy arrays (one sample) restricted to ``keys``.
    """

    def __init__(
        self,
        reader: Any,
        indices: np.ndarray,
        keys: Sequence[str],
        cache_shards: int = 4,
    ) -> None:
        self.reader = reader
        self.data_dir = Path(reader.path)
        self.indices = np.asarray(indices, dtype=np.int64)
        self.keys = tuple(keys)
        self.cache_shards = max(1, int(cache_shards))
        sizes = np.array([int(s["n"]) for s in reader.manifest["shards"]], dtype=np.int64)
        self.shard_files = [str(s["file"]) for s in reader.manifest["shards"]]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.shard_of = np.searchsorted(self.offsets, self.indices, side="right") - 1
        self._cache: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()

    def __len__(self) -> int:
        return int(self.indices.size)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_cache"] = OrderedDict()  # workers start with an empty cache
        return state

    def shard(self, i: int) -> dict[str, np.ndarray]:
        """Arrays of shard ``i`` (cached, LRU)."""
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        name = self.shard_files[i]
        try:
            arrays = self.reader.load_shard(i)
            data = {k: np.asarray(arrays[k]) for k in self.keys}
        except ChpfError:
            raise
        except Exception as err:
            raise DatasetError(
                f"{self.data_dir / name}: corrupt shard ({type(err).__name__}: {err})"
            ) from None
        n = int(self.offsets[i + 1] - self.offsets[i])
        for k, v in data.items():
            if v.shape[0] != n:
                raise DatasetError(
                    f"{self.data_dir / name}: array {k} has {v.shape[0]} samples, manifest says {n}"
                )
        self._cache[i] = data
        while len(self._cache) > self.cache_shards:
            self._cache.popitem(last=False)
        return data

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        g = int(self.indices[i])
        s = int(self.shard_of[i])
        local = g - int(self.offsets[s])
        data = self.shard(s)
        return {k: v[local] for k, v in data.items()}


class ShardBlockSampler(Sampler[int]):
    """Shuffles shards, then samples within ``shards_in_flight`` shards at a time (seeded).

    Each epoch reads every shard once; the order depends on ``seed`` and the epoch number, so
    all DDP ranks produce the same sequence (Lightning splits it between them).
    """

    def __init__(self, shard_of: np.ndarray, seed: int = 0, shards_in_flight: int = 2) -> None:
        self.shard_of = np.asarray(shard_of)
        self.seed = int(seed)
        self.k = max(1, int(shards_in_flight))
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return int(self.shard_of.size)

    def __iter__(self) -> Iterator[int]:
        rng = np.random.default_rng([self.seed, self.epoch])
        self.epoch += 1
        shards = np.unique(self.shard_of)
        rng.shuffle(shards)
        for b in range(0, shards.size, self.k):
            block = np.flatnonzero(np.isin(self.shard_of, shards[b : b + self.k]))
            yield from rng.permutation(block).tolist()


def collate(samples: list[dict[str, np.ndarray]]) -> dict[str, torch.Tensor]:
    """Stack a list of sample dicts into a dict of tensors (bool -> uint8, f16 -> f32)."""
    out: dict[str, torch.Tensor] = {}
    for k in samples[0]:
        a = np.stack([s[k] for s in samples])
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        elif a.dtype == np.float16:
            a = a.astype(np.float32)
        out[k] = torch.from_numpy(a)
    return out


def split_indices(
    sizes: Sequence[int], val_fraction: float, split: str, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Seeded train/val split of global sample indices, by whole shards or by sample.

    ``split="shard"`` holds out ``max(1, round(val_fraction * n_shards))`` shards when there are
    at least two shards (falls back to ``"index"`` otherwise). Returns sorted index arrays.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ConfigError(f"val_fraction must be in [0, 1), got {val_fraction}")
    if split not in ("shard", "index"):
        raise ConfigError(f"split must be 'shard' or 'index', got '{split}'")
    sizes = np.asarray(sizes, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    total = int(offsets[-1])
    rng = np.random.default_rng(seed)
    if val_fraction == 0.0:
        return np.arange(total), np.zeros(0, dtype=np.int64)
    if split == "shard" and sizes.size >= 2:
        n_val = min(sizes.size - 1, max(1, round(val_fraction * sizes.size)))
        val_shards = np.sort(rng.permutation(sizes.size)[:n_val])
        is_val = np.zeros(total, dtype=bool)
        for s in val_shards:
            is_val[offsets[s] : offsets[s + 1]] = True
    else:
        n_val = max(1, round(val_fraction * total))
        is_val = np.zeros(total, dtype=bool)
        is_val[rng.permutation(total)[:n_val]] = True
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


class ShardDataModule(pl.LightningDataModule):
    """Train/val loaders over one shard folder (optionally a separate validation folder).

    Args:
        data_dir: folder written by ``chpf-gen-data`` (manifest.json + shard_*.npz).
        val_dir: optional held-out folder; when given, ``val_fraction`` is ignored.
        batch_size: samples per batch.
        num_workers: DataLoader worker processes (0 = load in the main process).
        val_fraction: share of the data held out when ``val_dir`` is not given.
        split: "shard" (hold out whole shards) or "index" (hold out samples).
        val_max_samples: cap on validation samples (seeded subset), 0 = all.
        seed: seed of the split and of the shuffling.
        cache_shards: loaded shards kept in memory per worker.
        shards_in_flight: shards mixed together by the training sampler.
        mmap: memory-map the shards instead of reading them whole into the cache.
    """

    kind: str = "ae"
    keys: tuple[str, ...] = AE_KEYS

    def __init__(
        self,
        data_dir: str,
        val_dir: str | None = None,
        batch_size: int = 64,
        num_workers: int = 0,
        val_fraction: float = 0.1,
        split: str = "shard",
        val_max_samples: int = 2000,
        seed: int = 0,
        cache_shards: int = 4,
        shards_in_flight: int = 2,
        mmap: bool = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.data_dir = data_dir
        self.val_dir = val_dir
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.val_fraction = float(val_fraction)
        self.split = split
        self.val_max_samples = int(val_max_samples)
        self.seed = int(seed)
        self.cache_shards = int(cache_shards)
        self.shards_in_flight = int(shards_in_flight)
        self.mmap = bool(mmap)
        self.reader: Any = None
        self.val_reader: Any = None
        self.train_set: ShardSamples | None = None
        self.val_set: ShardSamples | None = None

    @property
    def manifest(self) -> dict[str, Any]:
        """The training folder's manifest (opens the folder if needed)."""
        if self.reader is None:
            self.reader = open_shards(self.data_dir, self.kind, self.mmap)
        return self.reader.manifest

    def check_crop_size(self, model_size: int) -> None:
        """ConfigError if the shards' crop size (train and val) differs from ``model_size``."""
        self.manifest  # noqa: B018  (opens the folder)
        check_crop_size(self.reader, self.data_dir, model_size)
        if self.val_dir is not None:
            if self.val_reader is None:
                self.val_reader = open_shards(self.val_dir, self.kind, self.mmap)
            check_crop_size(self.val_reader, self.val_dir, model_size)

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:
            return
        self.manifest  # noqa: B018
        sizes = [int(s["n"]) for s in self.reader.manifest["shards"]]
        if self.val_dir is not None:
            if self.val_reader is None:
                self.val_reader = open_shards(self.val_dir, self.kind, self.mmap)
            train_idx = np.arange(sum(sizes))
            val_sizes = [int(s["n"]) for s in self.val_reader.manifest["shards"]]
            val_idx, val_reader = np.arange(sum(val_sizes)), self.val_reader
        else:
            train_idx, val_idx = split_indices(sizes, self.val_fraction, self.split, self.seed)
            val_reader = self.reader
        if self.val_max_samples > 0 and val_idx.size > self.val_max_samples:
            rng = np.random.default_rng([self.seed, 1])
            val_idx = np.sort(rng.choice(val_idx, self.val_max_samples, replace=False))
        if train_idx.size == 0:
            raise DatasetError(f"{self.data_dir}: no training samples left after the split")
        self.train_set = ShardSamples(self.reader, train_idx, self.keys, self.cache_shards)
        self.val_set = ShardSamples(val_reader, val_idx, self.keys, self.cache_shards)

    def _loader(self, ds: ShardSamples, sampler: Sampler[int] | None, drop: bool) -> DataLoader:
        return DataLoader(
            ds,
            batch_size=self.batch_size,
            sampler=sampler,
            shuffle=False,
            num_workers=self.num_workers,
            collate_fn=collate,
            drop_last=drop,
            persistent_workers=self.num_workers > 0,
        )

    def train_dataloader(self) -> DataLoader:
        assert self.train_set is not None
        sampler = ShardBlockSampler(self.train_set.shard_of, self.seed, self.shards_in_flight)
        drop = len(self.train_set) > self.batch_size
        return self._loader(self.train_set, sampler, drop=drop)

    def val_dataloader(self) -> DataLoader:
        assert self.val_set is not None
        return self._loader(self.val_set, None, drop=False)


class AEDataModule(ShardDataModule):
    """Autoencoder samples: input_rgb (augmented), target_rgb (clean), target_mask, R_allo."""

    kind = "ae"
    keys = AE_KEYS


class PairDataModule(ShardDataModule):
    """Classifier pairs: obs_rgb, cand_rgb, aligned (1 = positive), angle_deg, visib_fract."""

    kind = "pairs"
    keys = PAIR_KEYS
