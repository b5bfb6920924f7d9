"""Fixtures: tiny fabricated shard folders in the chpf-gen-data layout (manifest + npz)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pytest

from chpf.atomic import atomic_save_npz
from data_gen.shards import make_manifest


def _rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    ).astype(np.float32)


def pattern(R: np.ndarray, size: int) -> np.ndarray:
    """A smooth RGB image (n,S,S,3) uint8 that depends on the rotation R (n,3,3)."""
    u = np.linspace(-1, 1, size)
    xx, yy = np.meshgrid(u, u)
    pix = np.stack([xx, yy, np.ones_like(xx)], -1)  # (S,S,3)
    phase = np.einsum("hwk,nck->nhwc", pix, R) * 3.0
    return (127.5 + 127.5 * np.sin(phase)).astype(np.uint8)


@functools.lru_cache(maxsize=1)
def _box_fingerprint() -> str:
    from chpf.objects import builtin_object, object_fingerprint

    return object_fingerprint(builtin_object(FIXTURE_OBJECT))


FIXTURE_OBJECT = "box"
"""The object the fabricated manifests name (their images are patterns, not renders): a
built-in, so that what renders from a data folder's object (the AE's validation codebook)
works."""


def write_shards(
    out: Path, kind: str, n: int, size: int = 16, per_shard: int = 16, seed: int = 0
) -> Path:
    """Write ``n`` fabricated samples of ``kind`` ('ae' or 'pairs') into ``out``."""
    rng = np.random.default_rng(seed)
    crop = {"size": size, "render_distance": 0.4, "focal": 3.6 * size}
    man = make_manifest(kind, FIXTURE_OBJECT, _box_fingerprint(), crop, seed, {}, per_shard, n)
    out.mkdir(parents=True, exist_ok=True)
    (out / "manifest.json").write_text(json.dumps(man))
    for entry in man["shards"]:
        m = entry["n"]
        R = _rotations(m, rng)
        if kind == "ae":
            target = pattern(R, size)
            noisy = target.astype(np.int16) + rng.integers(-20, 21, target.shape)
            arrays = {
                "input_rgb": np.clip(noisy, 0, 255).astype(np.uint8),
                "target_rgb": target,
                "target_mask": np.ones((m, size, size), dtype=bool),
                "R_allo": R,
                "visib_fract": rng.uniform(0.3, 1.0, m).astype(np.float32),
            }
        else:
            aligned = (np.arange(m) % 2).astype(np.uint8)
            R_c = np.where(aligned[:, None, None] == 1, R, _rotations(m, rng))
            angle = np.where(aligned == 1, rng.uniform(0, 10, m), rng.uniform(10, 180, m))
            arrays = {
                "obs_rgb": pattern(R, size),
                "cand_rgb": pattern(R_c, size),
                "cand_depth": np.full((m, size, size), 0.4, dtype=np.float16),
                "aligned": aligned,
                "obs_R_allo": R,
                "cand_R_allo": R_c.astype(np.float32),
                "angle_deg": angle.astype(np.float32),
                "visib_fract": rng.uniform(0.2, 1.0, m).astype(np.float32),
                "depth_ratio": np.ones(m, dtype=np.float32),
            }
        atomic_save_npz(out / entry["file"], arrays)
    return out


@pytest.fixture
def ae_dir(tmp_path: Path) -> Path:
    return write_shards(tmp_path / "ae", "ae", 64, per_shard=16)


@pytest.fixture
def pairs_dir(tmp_path: Path) -> Path:
    return write_shards(tmp_path / "pairs", "pairs", 64, per_shard=16)


@pytest.fixture
def shard_writer():
    """The ``write_shards(out, kind, n, size=16, per_shard=16, seed=0)`` helper."""
    return write_shards


@pytest.fixture
def pattern_images():
    """``(images (n,S,S,3) uint8, R (n,3,3))`` smooth rotation-dependent images."""

    def make(n: int, size: int = 16, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        R = _rotations(n, np.random.default_rng(seed))
        return pattern(R, size), R

    return make
