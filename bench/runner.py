"""Run a suite's jobs: resumable, in parallel worker processes, one shard of a cluster array.

Each job writes into ``OUT/jobs/JOB_ID/``: the method's BOP result CSV and frame log
(chpf.tracking.run_dataset, flushed frame by frame) and, once done, ``summary.json`` (written
atomically: per frame the visible fraction, the ADD, ADD-S and ADD(-S) errors as chpf-eval
scores them, alpha; plus frames, ms and the warnings of the run, e.g. weight collapses). A job
with a ``summary.json`` is finished and never run again, so an interrupted run loses nothing it
had finished and a rerun does only the rest.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bench.jobs import Job

SUMMARY = "summary.json"
_BUNDLES: dict[tuple[str, int, str, str], Any] = {}  # per worker process: loaded bundles


def job_dir(out: Path, job: Job) -> Path:
    return Path(out) / "jobs" / job.id


def is_done(out: Path, job: Job) -> bool:
    return (job_dir(out, job) / SUMMARY).is_file()


def _bundle(path: str, threads: int, precision: str, device: str):
    from chpf.bundle import Bundle

    key = (path, threads, precision, device)
    if key not in _BUNDLES:
        _BUNDLES[key] = Bundle.load(
            path, threads=threads, spin=False, precision=precision, device=device
        )
    return _BUNDLES[key]


def _finite_or_none(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None


def run_job(job: Job, out: Path, n_particles: int, config: str | None, threads: int) -> str:
    """Track one job and write its summary (see the module docstring); returns the job id."""
    from chpf.bop import DETECTIONS_SIM, BopDataset, read_results_csv
    from chpf.eval_cli import instance_errors
    from chpf.tracking.boxes import make_box_source
    from chpf.tracking.config import make_config
    from chpf.tracking.run_dataset import run_dataset
    from chpf.tracking.runlog import log_arrays, read_log
    from chpf.tracking.tracker import Tracker

    folder = job_dir(out, job)
    seq = job.seq
    cfg = make_config(config, filter={"n_particles": n_particles}, runtime={"threads": threads})
    tracker = Tracker(
        _bundle(seq.bundle, threads, cfg.runtime.precision, cfg.runtime.device),
        job.method,
        job.modality,
        seed=job.seed,
        config=cfg,
    )
    ds = BopDataset(seq.root)
    boxes = make_box_source(ds, "test", Path(seq.root) / DETECTIONS_SIM)
    with warnings.catch_warnings(record=True) as caught:  # kept in the summary, not printed
        warnings.simplefilter("always")
        runs = run_dataset(
            {job.method: tracker},
            ds,
            "test",
            [seq.scene_id],
            seq.obj_id,
            boxes,
            folder,
            seed=job.seed,
            progress=False,
        )
    run = runs[job.method]
    rows = read_results_csv(run.results) if run.results.is_file() else []
    scene = ds.scene("test", seq.scene_id)
    ims = scene.image_ids()
    index = {im: i for i, im in enumerate(ims)}
    info = ds.models_info()[seq.obj_id]
    err = {k: np.full(len(ims), np.inf) for k in ("add", "adds", "add_s")}
    if rows:
        e = instance_errors(seq.root, rows, "test", [seq.scene_id]).errors[seq.obj_id]
        for j, (_, im) in enumerate(e.keys):
            for k in err:
                err[k][index[im]] = getattr(e, k)[j]
    visib = np.ones(len(ims))
    for i, im in enumerate(ims):
        for p, gi in zip(scene.gt.get(im, []), scene.gt_info.get(im, []), strict=False):
            if p.obj_id == seq.obj_id:
                visib[i] = gi.visib_fract
                break
    log = log_arrays(read_log(run.log))
    alpha = np.full(len(ims), np.nan)
    ms = np.full(len(ims), np.nan)
    for im, a, t in zip(log["im_id"], log["alpha"], log["ms_total"], strict=True):
        alpha[index[int(im)]] = a
        ms[index[int(im)]] = t
    summary = {
        "job": job.id,
        "sequence": seq.key,
        "obj": seq.obj,
        "level": seq.level,
        "method": job.method,
        "modality": job.modality,
        "seed": job.seed,
        "diameter": float(info.diameter),
        "symmetric": bool(info.symmetries_discrete or info.symmetries_continuous),
        "threads": threads,
        "im_id": [int(i) for i in ims],
        "visib": [round(float(v), 4) for v in visib],
        **{k: [_finite_or_none(x) for x in v] for k, v in err.items()},
        "alpha": [_finite_or_none(x) for x in alpha],
        "ms": [_finite_or_none(x) for x in ms],
        "warnings": sorted({f"{w.category.__name__}: {w.message}" for w in caught}),
    }
    from chpf.atomic import atomic_write_text

    atomic_write_text(folder / SUMMARY, json.dumps(summary) + "\n")
    return job.id


def _job_main(args: tuple) -> str:
    """Worker entry: one library thread (BLAS/OpenCV) per process, then run_job."""
    return run_job(*args)


def run_jobs(
    out: Path,
    jobs: list[Job],
    n_particles: int,
    config: str | None,
    workers: int = 1,
    progress: bool = True,
) -> int:
    """Run the jobs of ``jobs`` that are not done yet; returns how many ran.

    ``workers`` processes (spawned), each with ``cpu_count // workers`` onnxruntime threads.
    """
    todo = [j for j in jobs if not is_done(out, j)]
    threads = max(1, (os.cpu_count() or 1) // max(1, workers))
    bar = tqdm(
        total=len(jobs),
        initial=len(jobs) - len(todo),
        desc="jobs",
        unit="job",
        disable=not progress or None,
    )
    try:
        if workers <= 1:
            for j in todo:
                run_job(j, out, n_particles, config, threads)
                bar.update(1)
        else:
            with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
                pending = {
                    pool.submit(_job_main, (j, out, n_particles, config, threads)) for j in todo
                }
                while pending:
                    finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for f in finished:
                        f.result()  # re-raise a worker's error
                        bar.update(1)
    finally:
        bar.close()
    return len(todo)
