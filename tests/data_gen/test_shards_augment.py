"""Shard I/O and augmentation building blocks."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.atomic import atomic_save_npz, npz_bytes
from chpf.errors import DatasetError
from data_gen import augment
from data_gen.config import default_config
from data_gen.shards import (
    ShardDataset,
    empty_shard,
    load_npz,
    make_manifest,
    prepare_output,
    shard_sizes,
)


def test_npz_is_deterministic_and_memory_mappable(tmp_path):
    arrays = empty_shard("pairs", 5, 16)
    arrays["angle_deg"][:] = np.arange(5)
    assert npz_bytes(arrays) == npz_bytes({k: v.copy() for k, v in arrays.items()})
    atomic_save_npz(tmp_path / "a.npz", arrays)
    for mmap in (False, True):
        back = load_npz(tmp_path / "a.npz", mmap=mmap)
        for k, v in arrays.items():
            assert back[k].dtype == v.dtype
            np.testing.assert_array_equal(back[k], v)
    assert not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())


def test_shard_sizes():
    assert shard_sizes(100, 40) == [40, 40, 20]
    assert shard_sizes(80, 40) == [40, 40]
    assert shard_sizes(3, 40) == [3]


def test_dataset_checks_fields(tmp_path):
    man = make_manifest(
        "ae", "x", "f", {"size": 16, "render_distance": 1.0, "focal": 57.6}, 0, {}, 4, 6
    )
    prepare_output(tmp_path, man, overwrite=False)
    a = empty_shard("ae", 4, 16)
    atomic_save_npz(tmp_path / "shard_00000.npz", a)
    b = empty_shard("ae", 2, 16)
    b["visib_fract"] = b["visib_fract"].astype(np.float64)  # wrong dtype
    atomic_save_npz(tmp_path / "shard_00001.npz", b)
    ds = ShardDataset(tmp_path)
    assert len(ds) == 6 and ds[3]["input_rgb"].shape == (16, 16, 3)
    with pytest.raises(DatasetError, match="visib_fract"):
        ds.load_shard(1)
    with pytest.raises(IndexError):
        ds[6]


def test_place_occluder_hits_target_fraction():
    rng = np.random.default_rng(0)
    obj = np.zeros((96, 96), bool)
    obj[30:70, 25:75] = True
    for target in (0.1, 0.3, 0.5, 0.7):
        for _ in range(5):
            _, occ = augment.random_shape(rng, 64)
            y0, x0 = augment.place_occluder(obj, occ, target, rng)
            got = augment.covered_pixels(obj, occ, y0, x0) / obj.sum()
            if occ.sum() > 1.3 * target * obj.sum():  # big enough to reach the target
                assert abs(got - target) < 0.08


def test_backgrounds_and_photometric_augmentation():
    cfg = default_config()
    bg = augment.Backgrounds.from_config(
        {**cfg["background"], "num_textures": 6, "texture_size": 64}
    )
    a = bg.sample(np.random.default_rng(1), 48)
    b = bg.sample(np.random.default_rng(1), 48)
    assert a.shape == (48, 48, 3) and a.dtype == np.uint8 and np.array_equal(a, b)
    a[:] = 0  # a fresh copy: the texture bank is not modified
    assert bg.textures.max() > 0 and np.array_equal(b, bg.sample(np.random.default_rng(1), 48))
    img = np.full((32, 32, 3), 128, np.uint8)
    cfg["color"]["prob"] = cfg["noise"]["prob"] = cfg["blur"]["prob"] = 1.0
    out = augment.augment_crop(img, np.random.default_rng(2), cfg)
    assert out.dtype == np.uint8 and out.shape == img.shape and not np.array_equal(out, img)
    # identity transform when every amount is zero
    M = augment.color_transform(
        np.random.default_rng(3),
        {"brightness": 0, "contrast": 0, "saturation": 0, "channel_gain": 0},
        np.array([1.0, 2, 3]),
    )
    np.testing.assert_allclose(M, np.hstack([np.eye(3), np.zeros((3, 1))]), atol=1e-6)


def test_image_folder_backgrounds(tmp_path):
    import cv2

    from chpf.errors import ConfigError

    with pytest.raises(ConfigError):
        augment.load_image_folder(tmp_path, 10, 32)
    cv2.imwrite(str(tmp_path / "a.png"), np.full((50, 80, 3), (255, 0, 0), np.uint8))
    imgs = augment.load_image_folder(tmp_path, 10, 32)
    assert imgs.shape == (1, 32, 32, 3) and tuple(imgs[0, 0, 0]) == (0, 0, 255)  # BGR -> RGB


def test_depth_noise():
    rng = np.random.default_rng(4)
    d = np.full((60, 80), 1.0, np.float32)
    d[20:40, 30:50] = 0.6
    d[:5] = 0
    cfg = default_config()["depth"]
    out = augment.depth_noise(d, rng, {**cfg, "hole_prob": 0.05})
    assert np.all(out[:5] == 0)  # missing stays missing
    valid = out > 0
    assert 0.8 < valid[5:].mean() < 1.0  # holes and dropped edges
    err = np.abs(out - d)[valid]
    assert 0.0005 < err.mean() < 0.01
