"""Tracking speed per method: frames per second end to end and milliseconds per stage.

`python -m chpf.benchmarks.track_bench [--bundle B] [--n-particles 50] [--frames 60]`

Frames: the bundle's object (a built-in one) rendered at 640x480 (f = 600 px) moving in front
of the camera, with its visible box as the detection (a random-noise image with a fixed box
when the object is not built-in). Each method's Tracker (RGB by default) is warmed up, then
``Tracker.step`` (image in, pose out) is timed. Columns: fps, total ms, ms of the stages, the
network ms (encoders + classifier head) and the share of the frame spent outside the networks
(crops, look-ups, motion model, resampling, estimate and Python overhead).
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


def bench_method(tracker: Tracker, frames, n_frames: int, warmup: int) -> dict[str, float]:
    """Mean ms per stage, end-to-end fps (from the mean frame time) and the median and 90th
    percentile frame times (ms; robust to other processes on a shared machine) of ``tracker``
    over n_frames (after warm-up)."""
    rgb, depth, K, boxes = frames
    use_depth = tracker.modality == "rgbd"
    n = len(boxes)
    for k in range(warmup):
        tracker.step(rgb[k % n], depth=depth[k % n] if use_depth else None, K=K, box=boxes[k % n])
    acc: dict[str, float] = {}
    frame_ms = np.empty(n_frames)
    for j in range(n_frames):
        k = (warmup + j) % n
        t0 = time.perf_counter()
        r = tracker.step(rgb[k], depth=depth[k] if use_depth else None, K=K, box=boxes[k])
        frame_ms[j] = (time.perf_counter() - t0) * 1000.0
        for s, v in r.stage_ms.items():
            acc[s] = acc.get(s, 0.0) + v
    wall = float(frame_ms.mean())
    out = {s: v / n_frames for s, v in acc.items()}
    out["wall"] = wall
    out["median"] = float(np.median(frame_ms))
    out["p90"] = float(np.percentile(frame_ms, 90))
    out["fps"] = 1000.0 / wall
    out["network"] = sum(out.get(s, 0.0) for s in NETWORK_STAGES)
    out["non_network_share"] = (wall - out["network"]) / wall
    return out


def format_table(rows: dict[str, dict[str, float]]) -> str:
    head = f"{'method':<11}{'fps':>7}{'ms':>7}{'med ms':>8}{'p90 ms':>8}"
    head += "".join(f"{s[:9]:>10}" for s in STAGES)
    head += f"{'network':>9}{'non-net':>9}"
    lines = [head, "-" * len(head)]
    for m, r in rows.items():
        cells = "".join(f"{r[s]:>10.2f}" if s in r else f"{'-':>10}" for s in STAGES)
        lines.append(
            f"{m:<11}{r['fps']:>7.1f}{r['wall']:>7.1f}{r['median']:>8.1f}{r['p90']:>8.1f}"
            f"{cells}{r['network']:>9.2f}"
            f"{r['non_network_share']:>9.0%}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m chpf.benchmarks.track_bench", description=__doc__)
    p.add_argument("--bundle", type=Path, default=None, help="bundle folder (default: shipped)")
    p.add_argument("--n-particles", type=int, default=50)
    p.add_argument("--frames", type=int, default=60, help="timed frames per method")
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--methods", default=",".join(method_names(paper_only=True)))
    p.add_argument("--modality", default="rgb", choices=("rgb", "rgbd"))
    p.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    p.add_argument("--spin", action="store_true", help="let onnxruntime threads busy-wait")
    p.add_argument("--config", type=Path, default=None, help="tracking options YAML")
    args = p.parse_args(argv)
    if args.bundle is None:
        from chpf.tracking.demo import shipped_bundle

        args.bundle = shipped_bundle()
    cfg = make_config(
        args.config, filter={"n_particles": args.n_particles}, runtime={"threads": args.threads}
    )
    run = cfg.runtime
    bundle = Bundle.load(
        args.bundle, args.threads, spin=args.spin, precision=run.precision, device=run.device
    )
    frames = bench_frames(bundle)
    rows = {}
    for m in [s.strip() for s in args.methods.split(",") if s.strip()]:
        tracker = Tracker(bundle, method=m, modality=args.modality, seed=0, config=cfg)
        rows[m] = bench_method(tracker, frames, args.frames, args.warmup)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"bundle {bundle.obj_info.name}: S={bundle.spec.size} E={bundle.embedding_dim} "
        f"K={bundle.codebook_size} shared_encoder={bundle.shares_encoder}; N={args.n_particles}, "
        f"{args.modality}, {W}x{H}, onnxruntime threads={args.threads} spin={args.spin}, "
        f"{os.cpu_count()} CPUs, load average {load:.2f}"
    )
    print(
        "fps and ms: mean frame time; med / p90: median and 90th percentile frame time; stages: "
        "mean ms; 'non-net' = share of the frame outside the networks"
    )
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
