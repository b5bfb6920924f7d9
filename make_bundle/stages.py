"""The stages, each calling the existing commands' Python entry points in-process."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from make_bundle.plan import MARGIN, OVERHEAD_S, TRAIN_MIN_S, Plan

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Ctx:
    obj: str
    unit: str
    out: Path
    work: Path
    plan: Plan
    workers: int
    seed: int
    trainer_args: list[str]
    progress: bool
    cache: Path
    deadline: float = float("inf")  # time.monotonic() by which every stage should be done
    notes: dict[str, str] = field(default_factory=dict)  # stage -> what changed at run time
    shard: tuple[int, int] | None = None  # (I, M): data stages write only job I's shards

    def d(self, name: str) -> Path:
        return self.work / name

    def train_seconds(self, stage: str, planned: int) -> int:
        """max_time of a training stage: ``planned``, shortened (never below TRAIN_MIN_S) so
        that its start-up and the estimated stages after it still end by the deadline; or, when
        the stages before it ran early (a budget plan), lengthened by its share of the time
        they saved (the autoencoder its part of the two trainings' planned time, the
        classifier the rest), keeping the plan's margin."""
        left = self.deadline - time.monotonic() - OVERHEAD_S[stage] - self.plan.after(stage)
        secs = int(max(TRAIN_MIN_S, min(planned, left)))
        if secs < planned:
            self.notes[stage] = f"max_time {planned} -> {secs} s (budget)"
            print(f"{stage}: max_time {planned} s -> {secs} s to end within the budget")
            return secs
        saved = left - planned - self.plan.budget_s * MARGIN / 2
        if self.plan.preset != "budget" or not math.isfinite(saved) or saved < 1:
            return secs
        p = self.plan
        share = p.ae_time_s / (p.ae_time_s + p.ch_time_s) if stage == "train_ae" else 1.0
        secs = int(planned + saved * share)
        self.notes[stage] = f"max_time {planned} -> {secs} s (earlier stages ran early)"
        print(f"{stage}: max_time {planned} s -> {secs} s, the time earlier stages saved")
        return secs


def _hms(seconds: int) -> str:
    s = int(seconds)
    return f"00:{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _check(code: int, what: str) -> None:
    if code not in (0, None):
        raise RuntimeError(f"{what} failed (exit {code})")


def _gen(c: Ctx, kind: str, out: str, n: int, pool: int, seed: int, extra: list[str]) -> None:
    from data_gen.cli import main

    argv = [
        kind, "--object", c.obj, "--unit", c.unit, "--out", str(c.d(out)), "--n", str(n),
        "--seed", str(seed), "--cache-dir", str(c.cache), "--workers", str(c.workers),
        "--size", str(c.plan.crop_size), "--codebook-size", str(c.plan.codebook_k),
        "--set", f"obs_pool.num_entries={pool}", *c.plan.extra_gen, *extra,
    ]  # fmt: skip
    if c.shard is not None:
        argv += ["--shard", str(c.shard[0]), "--num-shards", str(c.shard[1])]
    if not c.progress:
        argv.append("--no-progress")
    _check(main(argv), f"chpf-gen-data {kind}")


# ae crops cut at the true translation and all showing the object (held-out and validation)
CLEAN_AE = [
    "--set", "crop_jitter.xy_sigma=0", "--set", "crop_jitter.z_sigma=0",
    "--set", "empty_crops.ae_share=0",
]  # fmt: skip


def ae_data(c: Ctx) -> list[str]:
    _gen(c, "ae", "ae", c.plan.ae_n, c.plan.ae_pool, c.seed, [])
    if not c.plan.ae_val_n:  # a plan from before the validation set
        return ["ae"]
    _gen(c, "ae", "ae_val", c.plan.ae_val_n, c.plan.ae_pool, c.seed + 2, CLEAN_AE)
    return ["ae", "ae_val"]


def pairs_data(c: Ctx) -> list[str]:
    _gen(c, "pairs", "pairs", c.plan.pairs_n, c.plan.pairs_pool, c.seed, [])
    return ["pairs"]


def heldout(c: Ctx) -> list[str]:
    t = ["--set", "obs_pool.seed=1"]
    n, p, s = c.plan.test_n, c.plan.test_pool, c.seed + 1
    _gen(c, "ae", "ae_test", n, p, s, [*t, *CLEAN_AE])
    _gen(c, "pairs", "pairs_test", n, p, s, t)
    return ["ae_test", "pairs_test"]


def _train(c: Ctx, kind: str, cfg: str, data: str, run: str, steps: int, secs: int, extra):
    """chpf-train in its own process: Lightning's DDP launcher re-runs the command line of the
    process for the other ranks, which must be chpf-train's (not chpf-make-bundle's)."""
    secs = c.train_seconds(f"train_{kind}", secs)
    argv = [
        kind, "--config", str(ROOT / cfg), "--data.data_dir", str(c.d(data)),
        "--trainer.default_root_dir", str(c.d(run)), "--trainer.max_steps", str(steps),
        "--trainer.max_time", _hms(secs), "--model.lr_schedule_by_time", "true",
        "--seed_everything", str(c.seed), *extra,
    ]  # fmt: skip
    if not c.progress:  # Lightning's bar would fill a log with carriage returns
        argv += ["--trainer.enable_progress_bar", "false"]
    argv += c.trainer_args  # the user's --trainer.* options win
    path = os.environ.get("PYTHONPATH")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + (os.pathsep + path if path else "")}
    cmd = [sys.executable, "-m", "training.cli", *argv]
    t0 = time.monotonic()
    _check(subprocess.run(cmd, env=env).returncode, f"chpf-train {kind}")
    done = trained_steps(ckpt(c, run))
    note = f"{done} steps in {(time.monotonic() - t0) / 60:.1f} min"
    note += ", step cap" if done >= steps else ", to max_time"
    prev = c.notes.get(f"train_{kind}")
    c.notes[f"train_{kind}"] = f"{prev}; {note}" if prev else note
    print(f"train_{kind}: {note}", flush=True)


def trained_steps(path: Path) -> int:
    """Optimiser steps of a Lightning checkpoint (its ``global_step``)."""
    import torch

    return int(torch.load(path, map_location="cpu", weights_only=False, mmap=True)["global_step"])


def ckpt(c: Ctx, run: str) -> Path:
    return c.d(run) / "checkpoints" / "last.ckpt"


def train_ae(c: Ctx) -> list[str]:
    p = c.plan
    extra = ["--model.encoder.size", "32"] if p.preset == "tiny" else []
    if p.ae_val_n:
        extra += ["--data.val_dir", str(c.d("ae_val"))]
    _train(c, "ae", p.ae_config, "ae", "run_ae", p.ae_steps, p.ae_time_s, extra)
    return ["run_ae"]


def codebook(c: Ctx) -> list[str]:
    from training.codebook import main

    argv = ["--data", str(c.d("pairs")), "--k", str(c.plan.codebook_k)]
    argv += ["--out", str(c.d("codebook.npz")), "--cache-dir", str(c.cache)]
    _check(main([*argv, "--workers", str(c.workers)]), "training.codebook")
    return ["codebook.npz"]


def train_ch(c: Ctx) -> list[str]:
    p = c.plan
    extra = ["--model.init_from_ae", str(ckpt(c, "run_ae"))]
    if p.preset == "tiny":
        extra += ["--model.classifier.encoder.size", "32"]
    else:
        extra += ["--model.candidate_codebook", str(c.d("codebook.npz"))]
    _train(c, "ch", p.ch_config, "pairs", "run_ch", p.ch_steps, p.ch_time_s, extra)
    return ["run_ch"]


def export(c: Ctx) -> list[str]:
    from export.cli import main

    argv = [
        "--ae", str(ckpt(c, "run_ae")), "--ch", str(ckpt(c, "run_ch")), "--object", c.obj,
        "--unit", c.unit, "--out", str(c.out), "--codebook-size", str(c.plan.export_k),
        "--cache-dir", str(c.cache), "--workers", str(c.workers), "--overwrite",
    ]  # fmt: skip
    if not c.progress:
        argv.append("--quiet")
    _check(main(argv), "chpf-export")
    return []


def evaluate(c: Ctx) -> list[str]:
    from training.evaluate import main

    base = ["--ae", str(ckpt(c, "run_ae")), "--codebook", str(c.d("codebook.npz"))]
    base += ["--cache-dir", str(c.cache)]
    every = ["--max-samples", "0"]  # the held-out sets whole; the training family's 4,000
    ae = ["--data", str(c.d("ae_test")), "--json", str(c.d("eval_ae.json"))]
    _check(main([*base, *every, *ae]), "eval")
    ch = ["--ch", str(ckpt(c, "run_ch"))]
    for fam in ("pairs", "pairs_test"):  # training family and held-out family
        js = ["--pairs", str(c.d(fam)), "--json", str(c.d(f"eval_{fam}.json"))]
        _check(main([*base, *ch, *js, *(every if fam == "pairs_test" else [])]), "eval")
    return ["eval_ae.json", "eval_pairs.json", "eval_pairs_test.json"]


def sequence(c: Ctx) -> list[str]:
    from data_gen.cli import main

    argv = ["sequences", "--objects", c.obj, "--unit", c.unit, "--out", str(c.d("seq"))]
    argv += ["--frames", str(c.plan.seq_frames), "--num-scenes", "1", "--seed", str(c.seed)]
    if c.plan.preset == "tiny":
        argv += ["--width", "160", "--height", "120"]
    if not c.progress:
        argv.append("--no-progress")
    _check(main(argv), "chpf-gen-data sequences")
    return ["seq"]


def track(c: Ctx) -> list[str]:
    from chpf.bop import recorded_target_obj_id
    from chpf.track_cli import main

    argv = ["--bundle", str(c.out), "--dataset", str(c.d("seq")), "--method", "chpf,poserbpf"]
    argv += ["--obj-id", str(recorded_target_obj_id(c.d("seq"))), "--out", str(c.d("track"))]
    argv += ["--seed", str(c.seed)]
    if not c.progress:
        argv.append("--no-progress")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(argv)
    (c.work / "track_stdout.txt").write_text(buf.getvalue())
    print(buf.getvalue(), end="")
    _check(code, "chpf-track")
    return ["track", "track_stdout.txt"]


STAGES: list[tuple[str, Callable[[Ctx], list[str]]]] = [
    ("ae_data", ae_data),
    ("pairs_data", pairs_data),
    ("heldout", heldout),
    ("train_ae", train_ae),
    ("codebook", codebook),
    ("train_ch", train_ch),
    ("export", export),
    ("evaluate", evaluate),
    ("sequence", sequence),
    ("track", track),
]

STAGE_FNS = dict(STAGES)
# made by chpf-gen-data, which resumes them shard by shard (and writes shard jobs' parts)
DATA_STAGES = ("ae_data", "pairs_data", "heldout")

# outputs a stage removes before it starts again after an interruption
OUTPUTS = {
    "ae_data": ["ae", "ae_val"], "pairs_data": ["pairs"], "heldout": ["ae_test", "pairs_test"],
    "train_ae": ["run_ae"], "codebook": ["codebook.npz"], "train_ch": ["run_ch"],
    "evaluate": [], "sequence": ["seq"], "track": ["track"], "export": [],
}  # fmt: skip


def clean(c: Ctx, stage: str, data_too: bool = False) -> None:
    """Remove what ``stage`` makes before it runs again; the data stages' shards stay (they
    resume) unless ``data_too`` (the settings changed)."""
    if stage in DATA_STAGES and not data_too:
        return
    for name in OUTPUTS[stage]:
        p = c.d(name)
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def load_json(p: Path) -> Any:
    return json.loads(p.read_text()) if p.is_file() else None
