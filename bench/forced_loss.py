"""Forced loss (issue 23): does a tracker without detections find the object again after it jumps?

``python -m bench.forced_loss --out DIR`` takes the dev suite's unoccluded scenes (4 x 60 frames,
320x240, held-out family, seed 2000; ``--sequence-seed`` and ``--scenes`` make others of the same
design, to tune on scenes that are not reported) and shifts the target by ``--fraction`` (0.3) of
the image width between frames ``--jump`` and ``--jump`` + 1 (0-based 19 -> 20: im_id 21 is the
first shifted frame), along the camera's x axis towards the other half of the image; the ground
truth follows. The scenes are generated into ``--cache-dir``/forced_loss (their own folder: the
jump is not part of a suite's hash). Every method tracks them with the tracking YAML ``--config``
(default: ``search.box_source: estimate``, i.e. the first frame's box only) and the seeds; the
table printed gives per sequence and seed the frames from the jump to the first frame with ADD-S <
0.1 diameter ("-": not within the sequence; "not tracked before": ADD-S >= 0.1 diameter on the
frame before the jump), then per method the runs re-acquired within 30 frames, of all runs and
of those tracked before the jump.
``--figure PNG`` draws the search window's width, alpha and the set's doubt (what widens the
window: chpf.tracking.search_region.set_doubt), and the ADD-S error over the frames of the
first job that finds the object again (else the first job), tracked again with a Tracker (the
bench's summaries hold no region)."""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from bench.jobs import make_jobs
from bench.runner import run_jobs
from bench.sequences import build_sequences, default_cache_dir, resolve_bundles
from bench.suite import load_suite

TRACKED = 0.1  # ADD-S below this share of the diameter: tracked
WITHIN = 30  # frames from the jump: issue 23's re-acquisition target


@contextlib.contextmanager
def jumping_target(jump: int, fraction: float) -> Iterator[None]:
    """While active, data_gen's scene trajectories shift the target (object 0) by ``fraction``
    of the image width from frame ``jump`` on (module docstring)."""
    import data_gen.sequences as gen

    original = gen.scene_trajectories

    def jumped(scene_objs, cfg, rng):  # type: ignore[no-untyped-def]
        traj = original(scene_objs, cfg, rng)
        sc = cfg["sequences"]
        R, t = traj["R_w2c"][jump], traj["t_w2c"][jump]
        p = R @ traj["p_w"][jump, 0] + t
        side = -1.0 if p[0] > 0 else 1.0  # towards the other half of the image
        dx = side * fraction * sc["width"] * p[2] / sc["focal"]  # metres at the target's depth
        traj["p_w"][jump:, 0] += dx * R[0]  # R_w2c's first row: the camera's x axis
        return traj

    gen.scene_trajectories = jumped
    try:
        yield
    finally:
        gen.scene_trajectories = original


def _errors(summary: dict) -> np.ndarray:
    """A job summary's ADD-S per frame (F,) in diameters (inf where the filter gave no pose)."""
    return np.array([np.inf if v is None else v for v in summary["adds"]]) / summary["diameter"]


def reacquisition(summary: dict, jump: int) -> int | None:
    """Frames from the jump to the first tracked frame of a job's summary (None: none)."""
    hit = np.nonzero(_errors(summary)[jump:] < TRACKED)[0]
    return int(hit[0]) if hit.size else None


def tracked_before(summary: dict, jump: int) -> bool:
    """Whether a job's summary was tracked on the frame before the jump (a run that had lost
    the object already has nothing to re-acquire: an edge-on view, a wrong depth)."""
    return bool(_errors(summary)[jump - 1] < TRACKED)


def draw_figure(seq, config: str, seed: int, jump: int, path: Path) -> None:
    """Track ``seq`` with CH-PF (first box only) and plot region width, alpha with the set's
    doubt (what widens the region), and ADD-S."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from chpf.bop import DETECTIONS_SIM, BopDataset, read_detections
    from chpf.metrics import adds
    from chpf.tracking.search_region import set_doubt
    from chpf.tracking.tracker import Tracker

    ds = BopDataset(seq.root)
    scene = ds.scene("test", seq.scene_id)
    tracker = Tracker.from_bundle(seq.bundle, method="chpf", config=config, seed=seed)
    tracker.reset(seed=(seed, seq.scene_id))
    boxes = read_detections(Path(seq.root) / DETECTIONS_SIM)
    points, diameter = tracker.search.points, tracker.bundle.obj_info.diameter
    rows = []
    for k, im in enumerate(scene.image_ids()):
        rgb = scene.rgb(im)
        box = boxes.get((seq.scene_id, im, seq.obj_id)) if k == 0 else None
        r = tracker.step(rgb, K=scene.camera(im).K, box=box)
        gt = next(g for g in scene.gt[im] if g.obj_id == seq.obj_id)
        err = adds(points, r.R, r.t, gt.R, gt.t) / diameter if r.ok else np.nan
        width = np.nan if r.region is None else r.region[2] / rgb.shape[1]
        rows.append((im, width, r.alpha, set_doubt(r), err))
    im, width, alpha, doubt, err = np.array(rows).T
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    for ax, y, label in zip(
        axes,
        (width, alpha, err),
        ("search window width / image width", "alpha (dots), doubt", "ADD-S / diameter"),
        strict=True,
    ):
        ax.plot(im, y, ".-")
        ax.axvline(jump + 1, color="red", lw=0.8)
        ax.set_ylabel(label, fontsize=8)
    axes[1].plot(im, doubt, color="grey", lw=1.0)
    axes[2].axhline(TRACKED, color="green", lw=0.8, ls="--")
    axes[2].set_yscale("log")
    axes[2].set_xlabel("frame (red: the object jumps 0.3 of the image width)")
    fig.suptitle(f"CH-PF, first box only, sequence {seq.key}, seed {seed}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.forced_loss", description=__doc__)
    p.add_argument("--out", type=Path, required=True, help="output folder (resumable)")
    p.add_argument("--cache-dir", type=Path, default=None, help="sequence cache folder")
    p.add_argument("--config", default=None, help="tracking YAML (default: box_source estimate)")
    p.add_argument("--methods", default="chpf")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument(
        "--sequence-seed",
        type=int,
        default=None,
        help="the scenes' generator seed (default: the dev suite's, 2000)",
    )
    p.add_argument("--scenes", type=int, default=None, help="scenes (default: the dev suite's, 4)")
    p.add_argument("--jump", type=int, default=20, help="first shifted frame (0-based)")
    p.add_argument("--fraction", type=float, default=0.3, help="of the image width")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--figure", type=Path, default=None, help="PNG of the first sequence/seed")
    args = p.parse_args(argv)
    config = args.config
    if config is None:
        cfg = Path(tempfile.mkdtemp()) / "estimate.yaml"
        cfg.write_text("search:\n  box_source: estimate\n")
        config = str(cfg)
    sequences: dict[str, object] = {"occlusion": ["none"]}
    if args.sequence_seed is not None:
        sequences["seed"] = args.sequence_seed
    if args.scenes is not None:
        sequences["scenes_per_level"] = args.scenes
    suite = load_suite(
        "dev",
        {
            "methods": args.methods.split(","),
            "modalities": ["rgb"],
            "seeds": [int(s) for s in args.seeds.split(",")],
            "sequences": sequences,
            "tracking": {"config": config},
        },
    )
    suite.name = f"forced_loss_j{args.jump}_f{args.fraction:g}"
    cache = (args.cache_dir or default_cache_dir()) / "forced_loss"
    with jumping_target(args.jump, args.fraction):
        seqs = build_sequences(suite, resolve_bundles(suite), cache, 1)
    jobs = make_jobs(suite, seqs)
    run_jobs(args.out, jobs, suite.tracking.n_particles, config, args.workers, progress=False)
    print(f"frames from the jump to ADD-S < {TRACKED} diameter ('-': never)")
    found = []
    within: dict[str, list[tuple[bool, bool]]] = {}  # (re-acquired in time, tracked before)
    for job in jobs:
        summary = json.loads((args.out / "jobs" / job.id / "summary.json").read_text())
        n = reacquisition(summary, args.jump)
        before = tracked_before(summary, args.jump)
        print(f"{job.id}: {'-' if n is None else n}{'' if before else ' (not tracked before)'}")
        within.setdefault(job.method, []).append((n is not None and n <= WITHIN, before))
        if n is not None:
            found.append(job)
    for method, runs in within.items():
        hits, before = np.array(runs).T
        print(
            f"{method}: re-acquired within {WITHIN} frames in {hits.sum()} of {len(runs)} runs, "
            f"in {(hits & before).sum()} of the {before.sum()} tracked before the jump"
        )
    if args.figure is not None:
        shown = (found or jobs)[0]
        draw_figure(shown.seq, config, shown.seed, args.jump, args.figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
