"""Pools stream to disk: a build holds one chunk in memory, resumes after an interruption, and
is read back as memory maps."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest

from chpf.crops import CropSpec
from chpf.objects import builtin_object
from data_gen import pool as P
from data_gen import pool_store
from data_gen.config import default_config


def _cfg(n: int) -> dict:
    return {**default_config()["obs_pool"], "num_entries": n}


def _spec() -> CropSpec:
    return CropSpec.for_object(builtin_object("box").diameter, 32)


def test_building_a_pool_holds_one_chunk_not_the_pool(tmp_path):
    n, chunk = 4096, 64  # 64 chunks of 64 entries of 16 KB: a 64 MB pool

    def render(ranges):
        for a, b in ranges:
            yield {"x": np.full((b - a, 128, 128), a % 251, np.uint8), "y": np.arange(a, b)}

    chunks = [(a, a + chunk) for a in range(0, n, chunk)]
    build = pool_store.PoolBuild(n, chunks, render, {"kind": "test"})
    tracemalloc.start()
    try:
        arrays = pool_store.load_or_build(tmp_path / "p", ["x", "y"], True, lambda: build)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert arrays["x"].nbytes == 64 * 2**20
    assert peak < 4 * 2**20  # a few chunks; the old build held every chunk and their concatenation
    assert all(isinstance(a, np.memmap) for a in arrays.values())
    np.testing.assert_array_equal(arrays["y"], np.arange(n))
    assert (arrays["x"][::chunk, 0, 0] == np.arange(0, n, chunk) % 251).all()
    assert not pool_store.part_dir(tmp_path / "p").exists()
    rss = _rss_file_kb()
    assert int(arrays["x"][:, ::4096].sum()) > 0  # a consumer reading every entry...
    assert _rss_file_kb() - rss > 48 * 1024  # ...maps it in,
    pool_store.release(arrays.values())
    assert _rss_file_kb() - rss < 8 * 1024  # and gives the pages back between shards


def _rss_file_kb() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("RssFile:"))


def test_an_interrupted_build_resumes_where_it_stopped(tmp_path, monkeypatch):
    box, n = builtin_object("box"), 96  # 3 chunks of 32
    ref = P.obs_pool(box, _spec(), _cfg(n), tmp_path / "ref", progress=False)
    calls = []
    render = P._obs_task

    def failing(task):
        calls.append(len(task[3]["t"]))
        if len(calls) == 3:
            raise KeyboardInterrupt
        return render(task)

    monkeypatch.setattr(P, "_obs_task", failing)
    monkeypatch.setattr(pool_store, "CHECKPOINT_S", 0.0)
    with pytest.raises(KeyboardInterrupt):
        P.obs_pool(box, _spec(), _cfg(n), tmp_path / "c", progress=False)
    path = P.obs_pool_path(box, _spec(), _cfg(n), tmp_path / "c")
    part = pool_store.part_dir(path)
    assert not path.exists()
    assert json.loads((part / "progress.json").read_text())["done"] == 64  # 2 chunks on disk
    calls.clear()
    monkeypatch.setattr(P, "_obs_task", lambda task: (calls.append(1), render(task))[1])
    pool = P.obs_pool(box, _spec(), _cfg(n), tmp_path / "c", progress=False)
    assert len(calls) == 1  # only the missing chunk was rendered
    assert not part.exists()
    for f in P.ObsPool.FIELDS:  # the same bytes as a build in one go
        np.testing.assert_array_equal(getattr(pool, f), getattr(ref, f), err_msg=f)


def test_a_part_folder_of_other_settings_starts_again(tmp_path):
    part = tmp_path / ".part-obs-box-0123"
    part.mkdir()
    (part / "rgb.npy").write_bytes(b"stale")
    prog = {"key": "obs-box-other", "n": 64, "done": 32, "seconds": 1.0, "files": ["rgb.npy"]}
    (part / "progress.json").write_text(json.dumps(prog))
    chunks = [(0, 32), (32, 64)]
    assert pool_store._resume(part, "obs-box-other", 64, chunks) == (32, 1.0)
    assert pool_store._resume(part, "obs-box-0123", 64, chunks) == (0, 0.0)
    assert list(part.iterdir()) == []  # the stale rows are gone
