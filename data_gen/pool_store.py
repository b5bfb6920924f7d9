"""Pool folders on disk: streamed into memory-mapped ``.npy`` arrays, resumable, atomic.

A pool folder ``CACHE/{kind}-{name}-{key}/`` holds one ``.npy`` per array plus ``meta.json``;
``key`` fingerprints everything the pool depends on (``data_gen.pool``), so a pool made with
other settings is never read: another key names another folder.

Building streams: each chunk of entries is written into its rows of ``.npy`` files opened with
``numpy.lib.format.open_memmap`` (mapped only while the chunk is written), so the builder holds
one chunk in memory, never the pool. The files grow in ``.part-{folder}/`` beside the pool,
with ``progress.json`` (the key, the entries written so far, the build seconds) updated every
few seconds after the written rows are synced; an interrupted build resumes from there (a part
folder of another key or with a missing file starts again), and the finished folder is renamed
into place. A blocking lock file ``.{folder}.lock`` keeps concurrent builders of one pool
(parallel shard jobs) from writing it twice: the second waits and then reads the first's.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import mmap
import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from chpf.atomic import atomic_write_text

CHECKPOINT_S = 5.0  # seconds between progress checkpoints of a build


@dataclass
class PoolBuild:
    """How to build a pool of ``n`` entries.

    ``chunks``: consecutive entry ranges (a, b) covering 0..n; ``render(ranges)`` yields, in
    order, the arrays (name -> (b - a, ...)) of each range it is given; ``fixed``: arrays of all
    n entries known up front (poses), written when the rest is complete; ``meta``: meta.json.
    """

    n: int
    chunks: list[tuple[int, int]]
    render: Callable[[list[tuple[int, int]]], Iterable[dict[str, np.ndarray]]]
    meta: dict
    fixed: dict[str, np.ndarray] = field(default_factory=dict)


def load_arrays(path: Path, names: list[str], mmap: bool) -> dict[str, np.ndarray] | None:
    """The arrays ``names`` of a finished pool folder (read-only memory maps with ``mmap``), or
    None if there is none."""
    if not (path / "meta.json").is_file():
        return None
    try:
        return {n: np.load(path / f"{n}.npy", mmap_mode="r" if mmap else None) for n in names}
    except (OSError, ValueError):
        return None


def release(arrays: Iterable[np.ndarray]) -> None:
    """Unmap the pages of read-only memory-mapped arrays that this process has touched, so that
    its resident size does not grow with the share of a pool it has read (the pages stay in
    the page cache: a later read costs a minor fault, no disk read)."""
    for a in arrays:
        m = a.base if isinstance(a, np.memmap) else None
        if isinstance(m, mmap.mmap):
            m.madvise(mmap.MADV_DONTNEED)


@contextlib.contextmanager
def _build_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive (blocking) flock on ``.{path.name}.lock`` beside ``path``."""
    fd = os.open(path.parent / f".{path.name}.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def part_dir(path: Path) -> Path:
    """The folder a pool grows in before it is renamed to ``path``."""
    return path.parent / f".part-{path.name}"


def _resume(part: Path, key: str, n: int, chunks: list[tuple[int, int]]) -> tuple[int, float]:
    """(entries already written, build seconds so far) of the part folder; a part folder that
    does not match (another key or size, a missing file, not at a chunk end) is removed."""
    try:
        prog = json.loads((part / "progress.json").read_text())
        done, files = int(prog["done"]), prog["files"]
        ok = prog["key"] == key and prog["n"] == n and done in {b for _, b in chunks}
        ok = ok and all((part / f).is_file() for f in files)
    except (OSError, ValueError, KeyError, TypeError):
        ok = False
    if ok:
        return done, float(prog["seconds"])
    shutil.rmtree(part, ignore_errors=True)
    part.mkdir(parents=True)
    return 0, 0.0


def _write_rows(file: Path, a: int, rows: np.ndarray, n: int) -> None:
    """Write ``rows`` as entries a.. of the (n, ...) array in ``file`` (created on first use);
    the file is mapped only while the rows are copied in."""
    if not file.is_file():
        out = np.lib.format.open_memmap(file, "w+", rows.dtype, (n, *rows.shape[1:]))
    else:
        out = np.lib.format.open_memmap(file, "r+")
    out[a : a + len(rows)] = rows
    out.flush()
    del out


def _sync(part: Path) -> None:
    """fsync every array file of the part folder (the rows that progress.json will count)."""
    for f in part.glob("*.npy"):
        fd = os.open(f, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _checkpoint(part: Path, key: str, n: int, done: int, seconds: float) -> None:
    _sync(part)
    files = sorted(f.name for f in part.glob("*.npy"))
    prog = {"key": key, "n": n, "done": done, "seconds": round(seconds, 2), "files": files}
    atomic_write_text(part / "progress.json", json.dumps(prog))


def _stream(path: Path, build: PoolBuild) -> None:
    """Build the pool folder ``path`` through its part folder (resuming it) and rename it."""
    part, key = part_dir(path), path.name
    done, seconds = _resume(part, key, build.n, build.chunks)
    t0 = last = time.perf_counter()
    todo = [c for c in build.chunks if c[0] >= done]
    for (a, b), arrays in zip(todo, build.render(todo), strict=True):
        for name, rows in arrays.items():
            _write_rows(part / f"{name}.npy", a, rows, build.n)
        if time.perf_counter() - last >= CHECKPOINT_S and b < build.n:
            _checkpoint(part, key, build.n, b, seconds + time.perf_counter() - t0)
            last = time.perf_counter()
    for name, arr in build.fixed.items():
        np.save(part / f"{name}.npy", np.ascontiguousarray(arr))
    _sync(part)
    meta = {**build.meta, "build_seconds": round(seconds + time.perf_counter() - t0, 2)}
    (part / "progress.json").unlink(missing_ok=True)
    atomic_write_text(part / "meta.json", json.dumps(meta, indent=1) + "\n")
    os.rename(part, path)


def load_or_build(
    path: Path, names: list[str], mmap: bool, build: Callable[[], PoolBuild]
) -> dict[str, np.ndarray]:
    """The arrays ``names`` of the pool folder ``path`` (read-only memory maps with ``mmap``),
    built first by streaming ``build()`` into it if it is missing (see the module doc)."""
    arrays = load_arrays(path, names, mmap)
    if arrays is not None:
        return arrays
    path.parent.mkdir(parents=True, exist_ok=True)
    with _build_lock(path):
        if load_arrays(path, names, mmap) is None:  # not built meanwhile by another process
            _stream(path, build())
    arrays = load_arrays(path, names, mmap)
    if arrays is None:
        raise OSError(f"{path}: the pool just built cannot be read")
    return arrays
