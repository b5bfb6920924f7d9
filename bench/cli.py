"""``chpf-bench``: the paper's comparison as one command.

Usage::

    chpf-bench run --out DIR [--suite default|dev|quick|FILE.yaml] [--bundles B1,B2]
                   [--methods paper|a,b] [--seeds 0,1,2] [--modality rgb,rgbd] [--workers K]
                   [--shard I --num-shards M] [--cache-dir DIR] [--no-progress] [--no-report]
    chpf-bench report DIR
    chpf-bench merge --out DIR SHARD_DIR [SHARD_DIR ...]
    chpf-bench likelihoods DIR

``run`` builds (or reuses) the suite's held-out test sequences, runs every job that is not
finished yet (bench.runner) and writes the report (bench.report) unless it runs one shard of
several. ``merge`` gathers the finished jobs of shard folders of one suite, then reports.
``likelihoods`` scores L and C at the true pose on DIR's sequences by visible fraction
(bench.likelihoods).
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.jobs import make_jobs, shard
from bench.likelihoods import write_likelihoods
from bench.report import SUITE_FILE, TIMINGS_FILE, write_report
from bench.runner import SUMMARY, run_jobs
from bench.sequences import (
    SEQUENCES_FILE,
    build_sequences,
    default_cache_dir,
    resolve_bundles,
    sequences_from_json,
    sequences_to_json,
)
from bench.suite import load_suite, suite_record
from chpf.atomic import atomic_write_text
from chpf.console import run_main
from chpf.errors import ConfigError, OutputError
from chpf.outdir import differing_keys, lock_output_dir


def _items(text: str) -> list[Any]:
    """'0,1,2' -> [0, 1, 2]; 'rgb,rgbd' -> ['rgb', 'rgbd'] (numbers converted when they are)."""
    out: list[Any] = []
    for item in (s.strip() for s in text.split(",")):
        if item:
            out.append(int(item) if item.lstrip("-").isdigit() else item)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="chpf-bench", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="build the sequences, run the jobs, write the report")
    r.add_argument("--out", required=True, type=Path, help="output folder (resumable)")
    r.add_argument("--suite", default="default", help="default | dev | quick | a suite YAML file")
    r.add_argument(
        "--bundles",
        type=_items,
        help="bundle folders (shipped: the shipped ones; box, mug: one shipped bundle)",
    )
    r.add_argument("--methods", type=_items, help="registered methods or paper")
    r.add_argument("--seeds", type=_items, help="filter seeds, e.g. 0,1,2")
    r.add_argument("--modality", type=_items, help="rgb, rgbd or rgb,rgbd")
    r.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    r.add_argument("--shard", type=int, default=0, help="this shard's index (0-based)")
    r.add_argument("--num-shards", type=int, default=1, help="shards of the job list")
    r.add_argument("--cache-dir", type=Path, default=None, help="sequence cache folder")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("--no-report", action="store_true", help="skip the report")
    rep = sub.add_parser("report", help="(re)write DIR/report from the finished jobs")
    rep.add_argument("dir", type=Path)
    m = sub.add_parser("merge", help="gather shard folders of one suite into --out and report")
    m.add_argument("--out", required=True, type=Path)
    m.add_argument("shards", nargs="+", type=Path)
    lik = sub.add_parser(
        "likelihoods", help="L and C at the true pose on DIR's sequences, by visible fraction"
    )
    lik.add_argument("dir", type=Path)
    return p


def _likelihoods(folder: Path) -> int:
    path = folder / SEQUENCES_FILE
    if not path.is_file():
        raise OutputError(f"{folder}: not a chpf-bench run folder (no {SEQUENCES_FILE})")
    seqs = sequences_from_json(json.loads(path.read_text(encoding="utf-8")))
    with lock_output_dir(folder, "chpf-bench likelihoods"):
        print(write_likelihoods(folder, seqs))
    return 0


def _check_suite(folder: Path, record: dict[str, Any]) -> None:
    """Record the suite in ``folder``, or refuse a folder that holds another suite's results."""
    path = folder / SUITE_FILE
    if path.is_file():
        old = json.loads(path.read_text(encoding="utf-8"))
        if old.get("suite_hash") != record["suite_hash"]:
            keys = [k for k in differing_keys(old, record) if k != "suite_hash"]
            shown = ", ".join(keys[:4]) + (" ..." if len(keys) > 4 else "")
            raise OutputError(
                f"{folder}: holds results of another suite ({shown} differ); choose another --out"
            )
        return
    atomic_write_text(path, json.dumps(record, indent=1) + "\n")


def _run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {args.workers}")
    if args.num_shards < 1 or not 0 <= args.shard < args.num_shards:
        raise ConfigError(f"--shard {args.shard} --num-shards {args.num_shards}: out of range")
    names = {"bundles": "bundles", "methods": "methods", "seeds": "seeds", "modality": "modalities"}
    overrides = {k: getattr(args, a) for a, k in names.items() if getattr(args, a) is not None}
    suite = load_suite(args.suite, overrides)
    record = suite_record(suite)
    t0 = time.perf_counter()
    with lock_output_dir(args.out, "chpf-bench") as out:
        _check_suite(out, record)
        refs = resolve_bundles(suite)
        cache = args.cache_dir or default_cache_dir()
        seqs = build_sequences(suite, refs, cache, args.workers)
        atomic_write_text(out / SEQUENCES_FILE, json.dumps(sequences_to_json(seqs), indent=1))
        t_seq = time.perf_counter() - t0
        jobs = shard(make_jobs(suite, seqs), args.shard, args.num_shards)
        print(
            f"suite {suite.name}: {len(jobs)} jobs ({len(suite.methods)} methods x "
            f"{len(suite.modalities)} modalities x {len(seqs)} sequences x {len(suite.seeds)} "
            f"seeds{'' if args.num_shards == 1 else f', shard {args.shard}/{args.num_shards}'})"
            f" -> {out}",
            flush=True,
        )
        ran = run_jobs(
            out,
            jobs,
            suite.tracking.n_particles,
            suite.tracking.config,
            args.workers,
            progress=not args.no_progress,
        )
        wall = time.perf_counter() - t0
        timings = {
            "command": "chpf-bench " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            "wall_s": round(wall, 1),
            "sequences_s": round(t_seq, 1),
            "jobs_s": round(wall - t_seq, 1),
            "jobs_run": ran,
            "workers": args.workers,
        }
        atomic_write_text(out / TIMINGS_FILE, json.dumps(timings, indent=1) + "\n")
        print(
            f"{ran} jobs run ({len(jobs) - ran} already done) in {wall:.0f} s "
            f"({t_seq:.0f} s for the sequences)",
            flush=True,
        )
        if args.num_shards == 1 and not args.no_report:
            print(f"report: {write_report(out)}")
    return 0


def _merge(args: argparse.Namespace) -> int:
    with lock_output_dir(args.out, "chpf-bench merge") as out:
        records = []
        for d in args.shards:
            path = d / SUITE_FILE
            if not path.is_file():
                raise OutputError(f"{d}: not a chpf-bench folder (no {SUITE_FILE})")
            records.append((d, json.loads(path.read_text(encoding="utf-8"))))
        target = out / SUITE_FILE
        first = json.loads(target.read_text(encoding="utf-8")) if target.is_file() else None
        ref_dir, ref = (out, first) if first else records[0]
        for d, rec in records:
            if rec.get("suite_hash") != ref.get("suite_hash"):
                raise OutputError(
                    f"{d}: results of another suite ({rec.get('name')!r}, hash "
                    f"{rec.get('suite_hash')}) than {ref_dir} ({ref.get('name')!r}, hash "
                    f"{ref.get('suite_hash')})"
                )
        _check_suite(out, ref)
        if not (out / SEQUENCES_FILE).is_file():
            shutil.copyfile(records[0][0] / SEQUENCES_FILE, out / SEQUENCES_FILE)
        copied = 0
        for d, _ in records:
            for summary in sorted((d / "jobs").glob(f"*/{SUMMARY}")):
                dest = out / "jobs" / summary.parent.name
                if not (dest / SUMMARY).is_file():
                    shutil.rmtree(dest, ignore_errors=True)
                    shutil.copytree(summary.parent, dest)
                    copied += 1
        print(f"merged {copied} finished jobs from {len(records)} folder(s) into {out}")
        print(f"report: {write_report(out)}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``chpf-bench``; returns the exit code."""
    args = build_parser().parse_args(argv)
    if args.cmd == "run":
        return _run(args)
    if args.cmd == "merge":
        return _merge(args)
    if args.cmd == "likelihoods":
        return _likelihoods(args.dir)
    with lock_output_dir(args.dir, "chpf-bench report"):
        print(f"report: {write_report(args.dir)}")
    return 0


cli = run_main(main)

if __name__ == "__main__":
    cli()
