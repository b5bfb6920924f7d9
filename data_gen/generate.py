"""Sharded, resumable, multi-process generation of pairs / ae datasets.

Shard ``i`` is generated from its own random stream ``SeedSequence([seed, kind, i])`` in fixed
chunks, so its bytes do not depend on ``--workers``, ``--shard/--num-shards`` or on which
shards a resumed run still had to make.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from chpf.atomic import atomic_save_npz
from data_gen import config as C
from data_gen import shards as sh
from data_gen.compose import Composer, ComposerContext, ComposerSetup, build_pools

KIND_TAG = {"pairs": 1, "ae": 2}
CHUNK = 64  # samples per composition call (fixed: part of the byte-exact output definition)


def shard_rng(seed: int, kind: str, i: int) -> np.random.Generator:
    """The random stream of shard ``i``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), KIND_TAG[kind], int(i)]))


def make_shard(composer: Composer, seed: int, i: int, n: int, progress=None) -> dict:
    """Arrays of shard ``i`` with ``n`` samples; ``progress(k)`` is called per chunk."""
    rng = shard_rng(seed, composer.kind, i)
    parts = []
    for a in range(0, n, CHUNK):
        k = min(CHUNK, n - a)
        parts.append(composer.generate(rng, k))
        if progress is not None:
            progress(k)
    composer.release_pages()  # resident size stays at one shard's share of the pools
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


# ----------------------------------------------------------------------------- worker processes

_W: dict = {}


def _init_worker(setup: ComposerSetup, counter, next_task) -> None:
    _W["composer"] = Composer(setup)
    _W["counter"] = counter
    _W["next"] = next_task


def _bump(k: int) -> None:
    with _W["counter"].get_lock():
        _W["counter"].value += k


def _claim(next_task, n_tasks: int) -> int | None:
    """Index of the next unclaimed task (shared between all processes), or None."""
    with next_task.get_lock():
        j = next_task.value
        if j >= n_tasks:
            return None
        next_task.value = j + 1
        return j


def _drain(tasks: list[tuple]) -> list[int]:
    """Worker loop: claim tasks (out_dir, seed, shard, n) until none is left; make them."""
    made = []
    while (j := _claim(_W["next"], len(tasks))) is not None:
        out_dir, seed, i, n = tasks[j]
        arrays = make_shard(_W["composer"], seed, i, n, _bump)
        atomic_save_npz(Path(out_dir) / sh.shard_name(i), arrays)
        made.append(i)
    return made


# ----------------------------------------------------------------------------- driver


@dataclass
class GenResult:
    written: list[int]
    skipped: list[int]
    seconds: float
    samples: int


def select_shards(num_total: int, shard: int | None, num_shards: int) -> list[int]:
    """Shard indices job ``shard`` of ``num_shards`` makes (round robin); all if shard is None."""
    if shard is None:
        return list(range(num_total))
    return [i for i in range(num_total) if i % num_shards == shard]


def manifest_for(ctx: ComposerContext, n: int, seed: int) -> dict:
    """The manifest of a ``ctx.kind`` dataset of ``n`` samples."""
    from chpf.geometry import RotationGrid
    from chpf.objects import object_fingerprint
    from data_gen.rotations import grid_spacing_deg

    obj, cfg = ctx.obj, ctx.cfg
    secs = C.PAIRS_SECTIONS if ctx.kind == "pairs" else C.AE_SECTIONS
    extra = {
        "object_info": {
            "name": obj.name,
            "obj_id": int(obj.obj_id),
            "diameter": float(obj.diameter),
            "symmetries_discrete": [np.asarray(T).tolist() for T in obj.symmetries_discrete],
            "symmetries_continuous": [
                {k: np.asarray(v).tolist() for k, v in s.items()} for s in obj.symmetries_continuous
            ],
        },
        "object_source": {"path": obj.source, "unit": obj.unit},
        "window_size": int(np.ceil(cfg["obs_pool"]["margin"] * ctx.spec.size - 1e-9)),
    }
    if ctx.kind == "pairs":
        p = cfg["pairs"]
        spacing = grid_spacing_deg(RotationGrid.uniform(cfg["codebook"]["size"]))
        extra["labels"] = {
            "angle_deg": "symmetry-aware geodesic angle between obs_R_allo and cand_R_allo",
            "positive_perturbation_deg": {
                "sigma": p["pos_rot_sigma_deg"],
                "max": p["pos_rot_max_deg"],
            },
            "codebook_grid_spacing_deg": spacing,
            "positive_max_angle_deg": round(p["pos_rot_max_deg"] + spacing["max"], 3),
            "negative_min_angle_deg": p["neg_min_angle_deg"],
        }
    return sh.make_manifest(
        kind=ctx.kind,
        object_name=obj.name,
        object_fingerprint=object_fingerprint(obj),
        crop=ctx.spec.to_dict(),
        seed=seed,
        config=C.sections(cfg, secs),
        samples_per_shard=cfg["shards"]["samples_per_shard"],
        num_samples=n,
        extra=extra,
    )


def generate(
    ctx: ComposerContext,
    out_dir: str | Path,
    n: int,
    seed: int,
    shard: int | None = None,
    num_shards: int = 1,
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
) -> GenResult:
    """Generate (the selected shards of) a pairs/ae dataset into ``out_dir``; resume-safe."""
    t0 = time.perf_counter()
    out = Path(out_dir)
    manifest = manifest_for(ctx, n, seed)
    sh.prepare_output(out, manifest, overwrite, dry_run=True)  # refuse before any long work
    setup = build_pools(ctx, workers=workers, progress=progress)
    sh.prepare_output(out, manifest, overwrite)
    entries = manifest["shards"]
    mine = select_shards(len(entries), shard, num_shards)
    todo = [i for i in mine if not sh.shard_complete(out, manifest, i)]
    skipped = [i for i in mine if i not in todo]
    total = sum(entries[i]["n"] for i in todo)
    bar = tqdm(
        total=total,
        desc=f"{ctx.kind} {out.name}",
        unit="sample",
        disable=not progress or None,
        smoothing=0.1,
    )
    try:
        if workers <= 1 or len(todo) <= 1:
            composer = Composer(setup) if todo else None
            for i in todo:
                arrays = make_shard(composer, seed, i, entries[i]["n"], bar.update)
                atomic_save_npz(out / entries[i]["file"], arrays)
        else:
            # workers - 1 spawned processes and this one claim shards from a shared counter
            # (this process starts at once, while the others are still starting up)
            mpc = mp.get_context("spawn")
            counter, next_task = mpc.Value("q", 0), mpc.Value("q", 0)
            tasks = [(str(out), seed, i, entries[i]["n"]) for i in todo]
            n_children = min(workers, len(todo)) - 1
            with mpc.Pool(n_children, _init_worker, (setup, counter, next_task)) as pool:
                results = [pool.apply_async(_drain, (tasks,)) for _ in range(n_children)]
                _init_worker(setup, counter, next_task)

                def tick(k: int) -> None:
                    _bump(k)
                    bar.update(counter.value - bar.n)

                while (j := _claim(next_task, len(tasks))) is not None:
                    _, _, i, n = tasks[j]
                    arrays = make_shard(_W["composer"], seed, i, n, tick)
                    atomic_save_npz(out / entries[i]["file"], arrays)
                for r in results:
                    while not r.ready():
                        r.wait(0.2)
                        bar.update(counter.value - bar.n)
                    r.get()  # re-raises a worker's error
                bar.update(counter.value - bar.n)
                _W.clear()
    finally:
        bar.close()
    return GenResult(todo, skipped, time.perf_counter() - t0, total)
