"""Shared tiny settings for the data_gen tests: one small pool cache for the whole session."""

from __future__ import annotations

import pytest

# tiny pools and shards: S = 32, 200 codebook entries, 50 observation entries
TINY_SETS = [
    "crop.size=32",
    "codebook.size=200",
    "obs_pool.num_entries=50",
    "occluder_pool.objects=[box, can]",
    "occluder_pool.num_entries=20",
    "background.num_textures=8",
    "background.texture_size=64",
    "shards.samples_per_shard=40",
]


def tiny_args(cache_dir, *extra_sets: str) -> list[str]:
    """CLI arguments selecting the tiny settings and the session pool cache."""
    args = ["--cache-dir", str(cache_dir), "--no-progress"]
    for s in (*TINY_SETS, *extra_sets):
        args += ["--set", s]
    return args


@pytest.fixture(scope="session")
def tiny_sets() -> list[str]:
    """The tiny ``--set`` overrides."""
    return list(TINY_SETS)


@pytest.fixture(scope="session")
def make_args(pool_cache):
    """``make_args(*extra_sets)`` -> CLI arguments with the tiny settings and the shared cache."""
    return lambda *extra: tiny_args(pool_cache, *extra)


@pytest.fixture(scope="session")
def pool_cache(tmp_path_factory):
    """A pool cache folder shared by the session (pools are built on first use)."""
    return tmp_path_factory.mktemp("pool_cache")
