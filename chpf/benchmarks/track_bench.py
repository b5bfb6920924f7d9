"""Tracking speed per method: frames per second end to end and milliseconds per stage.

`python -m chpf.benchmarks.track_bench [--bundle B] [--n-particles 25,50,100,200]
[--objects 1,2,4] [--frames 60] [--long-run 2000]`

Frames: the bundle's object (a built-in one) rendered at 640x480 (f = 600 px) moving in front
of the camera, with its visible box as the detection (a random-noise image with a fixed box
when the object is not built-in). Each method's Tracker (RGB by default) is warmed up, then
``Tracker.step`` (image in, pose out) is timed. Columns: fps, total ms, ms of the stages, the
network ms (encoders + classifier head), the share of the frame spent outside the networks
(crops, look-ups, motion model, resampling, estimate and Python overhead) and the process's
resident memory after the row (MB; the peak of the whole run is printed last). Several values of
``--n-particles`` or ``--objects`` (trackers stepping the same frames in turn, as for several
tracked objects; the row's times are per frame, all objects together) give one row each.
``--long-run F`` steps the first method's tracker over F frames (the rendered ones in a loop)
and prints its resident memory and frame time at the start, the middle and the end: nothing
should grow with the sequence's length.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from chpf.bundle import Bundle
from chpf.geometry import axis_angle_to_matrix
from chpf.tracking.config import make_config
from chpf.tracking.methods import method_names
from chpf.tracking.multi import MultiTracker
from chpf.tracking.runlog import NETWORK_STAGES
from chpf.tracking.tracker import Tracker

STAGES = ("crop", "encode", "ch_encode", "lookup", "head", "depth", "predict", "weigh",
          "estimate", "resample")  # fmt: skip
W, H, F = 640, 480, 600.0


def bench_frames(bundle: Bundle, n: int = 30):
    """(rgb (n,H,W,3), depth (n,H,W), K, boxes) of the bundle's object moving slowly."""
    from chpf.objects import BUILTIN_OBJECTS

    K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(0)
    name = bundle.obj_info.name
    if name not in BUILTIN_OBJECTS:
        rgb = rng.integers(0, 255, (n, H, W, 3), dtype=np.uint8)
        return rgb, np.full((n, H, W), 0.8, np.float32), K, [(260.0, 180.0, 120.0, 120.0)] * n
    from chpf.objects import get_object
    from chpf.render import Renderer

    obj = get_object(name)
    i = np.arange(n, dtype=np.float64)
    R = axis_angle_to_matrix(np.stack([0.6 + 0.02 * i, 0.4 - 0.015 * i, 0.2 + 0.01 * i], -1))
    z = 5.0 * obj.diameter
    t = np.stack([-0.05 * z + 0.003 * i, 0.02 * z - 0.001 * i, z + 0.002 * i], -1)
    rgbs = np.empty((n, H, W, 3), np.uint8)
    depths = np.empty((n, H, W), np.float32)
    boxes = []
    bg = rng.integers(60, 200, (H, W, 3), dtype=np.uint8)
    with Renderer(W, H) as r:
        for k in range(n):
            out = r.render([(obj, R[k], t[k])], K)
            m = out.masks[0]
            rgbs[k] = np.where(m[..., None], out.rgb, bg)
            depths[k] = np.where(m, out.depth, 2.0 * z)
            ys, xs = np.nonzero(m)
            boxes.append(
                (float(xs.min()), float(ys.min()), float(np.ptp(xs) + 1), float(np.ptp(ys) + 1))
            )
    return rgbs, depths, K, boxes


def bench_method(trackers: list[Tracker], frames, n_frames: int, warmup: int) -> dict[str, float]:
    """Mean ms per stage, end-to-end fps (from the mean frame time) and the median and 90th
    percentile frame times (ms; robust to other processes on a shared machine) of the
    ``trackers`` (one per tracked object, stepped in turn on each frame by a MultiTracker, as
    chpf-track does with several --bundle) over n_frames (after
    warm-up); times are per frame, all trackers together."""
    rgb, depth, K, boxes = frames
    n = len(boxes)
    multi = MultiTracker(trackers, obj_ids=range(len(trackers)))  # as chpf-track steps them

    def step(k: int) -> dict[str, float]:
        stages: dict[str, float] = {}
        d = depth[k] if multi.modality == "rgbd" else None
        for r in multi.step(rgb[k], depth=d, K=K, boxes=[boxes[k]] * len(trackers)):
            for s, v in r.stage_ms.items():
                stages[s] = stages.get(s, 0.0) + v
        return stages

    for k in range(warmup):
        step(k % n)
    acc: dict[str, float] = {}
    frame_ms = np.empty(n_frames)
    for j in range(n_frames):
        t0 = time.perf_counter()
        stages = step((warmup + j) % n)
        frame_ms[j] = (time.perf_counter() - t0) * 1000.0
        for s, v in stages.items():
            acc[s] = acc.get(s, 0.0) + v
    wall = float(frame_ms.mean())
    out = {s: v / n_frames for s, v in acc.items()}
    out["wall"] = wall
    out["median"] = float(np.median(frame_ms))
    out["p90"] = float(np.percentile(frame_ms, 90))
    out["fps"] = 1000.0 / wall
    out["network"] = sum(out.get(s, 0.0) for s in NETWORK_STAGES)
    out["non_network_share"] = (wall - out["network"]) / wall
    out["rss_mb"] = resident_mb()
    return out


def resident_mb() -> float:
    """This process's resident memory now (MB; nan where /proc is missing)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return float("nan")
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def peak_resident_mb() -> float:
    """This process's peak resident memory so far (MB; nan where getrusage cannot say)."""
    try:
        import resource
    except ImportError:  # Windows has no resource module
        return float("nan")
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux
    return kb * 1024 / 1e6


def long_run(tracker: Tracker, frames, n_frames: int) -> list[tuple[int, float, float]]:
    """(frame, resident MB, mean ms of the last 50 frames) at the start, middle and end of
    ``n_frames`` steps of ``tracker`` over the frames in a loop."""
    rgb, _, K, boxes = frames
    marks = {0, n_frames // 2, n_frames - 1}
    out, recent = [], []
    for j in range(n_frames):
        k = j % len(boxes)
        t0 = time.perf_counter()
        tracker.step(rgb[k], K=K, box=boxes[k])
        recent = [*recent[-49:], (time.perf_counter() - t0) * 1000.0]
        if j in marks:
            out.append((j + 1, resident_mb(), float(np.mean(recent))))
    return out


def format_table(rows: dict[str, dict[str, float]]) -> str:
    head = f"{'run':<22}{'fps':>7}{'ms':>7}{'med ms':>8}{'p90 ms':>8}"
    head += "".join(f"{s[:9]:>10}" for s in STAGES)
    head += f"{'network':>9}{'non-net':>9}{'RSS MB':>8}"
    lines = [head, "-" * len(head)]
    for m, r in rows.items():
        cells = "".join(f"{r[s]:>10.2f}" if s in r else f"{'-':>10}" for s in STAGES)
        lines.append(
            f"{m:<22}{r['fps']:>7.1f}{r['wall']:>7.1f}{r['median']:>8.1f}{r['p90']:>8.1f}"
            f"{cells}{r['network']:>9.2f}"
            f"{r['non_network_share']:>9.0%}{r.get('rss_mb', float('nan')):>8.0f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m chpf.benchmarks.track_bench", description=__doc__)
    p.add_argument("--bundle", type=Path, default=None, help="bundle folder (default: shipped)")
    p.add_argument("--n-particles", default="50", help="N, or a list: 25,50,100,200")
    p.add_argument("--objects", default="1", help="objects tracked at once, or a list: 1,2,4")
    p.add_argument("--frames", type=int, default=60, help="timed frames per row")
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--methods", default=",".join(method_names(paper_only=True)))
    p.add_argument("--modality", default="rgb", choices=("rgb", "rgbd"))
    p.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    p.add_argument("--spin", action="store_true", help="let onnxruntime threads busy-wait")
    p.add_argument("--config", type=Path, default=None, help="tracking options YAML")
    p.add_argument("--long-run", type=int, default=0, help="frames of a memory run (0 = none)")
    args = p.parse_args(argv)
    if args.bundle is None:
        from chpf.tracking.demo import shipped_bundle

        args.bundle = shipped_bundle()
    counts = [int(v) for v in args.n_particles.split(",")]
    objects = [int(v) for v in args.objects.split(",")]
    methods = [s.strip() for s in args.methods.split(",") if s.strip()]
    cfg = make_config(args.config, runtime={"threads": args.threads})
    run = cfg.runtime
    bundle = Bundle.load(
        args.bundle, args.threads, spin=args.spin, precision=run.precision, device=run.device
    )
    rss_start = resident_mb()
    frames = bench_frames(bundle)
    rows = {}
    for m in methods:
        for n in counts:
            cfg_n = make_config(cfg, filter={"n_particles": n})
            for k in objects:
                trackers = [Tracker(bundle, m, args.modality, i, cfg_n) for i in range(k)]
                label = m + (f" N={n}" if len(counts) > 1 else "") + (f" x{k}" if k > 1 else "")
                rows[label] = bench_method(trackers, frames, args.frames, args.warmup)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"bundle {bundle.obj_info.name}: S={bundle.spec.size} E={bundle.embedding_dim} "
        f"K={bundle.codebook_size} shared_encoder={bundle.shares_encoder} "
        f"{bundle.precision}; N={args.n_particles}, {args.modality}, {W}x{H}, onnxruntime "
        f"threads={args.threads} spin={args.spin}, {os.cpu_count()} CPUs, load average "
        f"{load:.2f}, resident {rss_start:.0f} MB after loading"
    )
    print(
        "fps and ms: mean frame time; med / p90: median and 90th percentile frame time; stages: "
        "mean ms; 'non-net' = share of the frame outside the networks; RSS MB: resident memory "
        "after the row"
    )
    print(format_table(rows))
    if args.long_run > 0:
        cfg_n = make_config(cfg, filter={"n_particles": counts[0]})
        tracker = Tracker(bundle, methods[0], args.modality, config=cfg_n)
        print(f"long run, {methods[0]} N={counts[0]}: frame, resident MB, ms (last 50 frames)")
        for j, mb, ms in long_run(tracker, frames, args.long_run):
            print(f"{j:>8} {mb:>10.0f} {ms:>8.1f}")
    print(f"peak resident memory of this run: {peak_resident_mb():.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
