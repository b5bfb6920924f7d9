"""Benchmark of the batched metrics and the rotation-grid lookup.

`python -m chpf.benchmarks.metrics_bench` prints the median wall time of: adds_batch (1 and 2
KD-tree threads) and add_batch for 1,000 poses of a 2,000-point model, and RotationGrid.nearest
for 50 rotations against a 20,000-entry grid.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from chpf.geometry import RotationGrid, perturb_rotations, random_rotations
from chpf.metrics import add_batch, adds_batch


def _median_seconds(fn: Callable[[], object], runs: int, calls: int = 1) -> float:
    """Median over `runs` of the mean time of `calls` calls (seconds); one warm-up call first."""
    fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls)
    return float(np.median(times))


def _model_points(m: int, rng: np.random.Generator) -> np.ndarray:
    """m points (m, 3) on an ellipsoid surface with semi-axes 5 x 3 x 10 cm (metres)."""
    d = rng.standard_normal((m, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * np.array([0.05, 0.03, 0.10])


def run(runs: int = 3, poses: int = 1000, points: int = 2000, seed: int = 0) -> list[dict]:
    """Time the metrics and the grid lookup; one dict per row (name, setup, median_ms, runs)."""
    rng = np.random.default_rng(seed)
    pts = _model_points(points, rng)
    R_gt = random_rotations(poses, rng)
    R_est = perturb_rotations(R_gt, 0.1, rng)  # tracking-like errors: ~9 deg, ~1.6 cm (mean)
    t_gt = rng.uniform(-0.2, 0.2, (poses, 3)) + np.array([0.0, 0.0, 1.0])
    t_est = t_gt + rng.normal(0.0, 0.01, (poses, 3))
    setup = f"P={poses} poses, M={points} points"
    rows = [
        (
            "adds_batch (workers=1)",
            setup,
            lambda: adds_batch(pts, R_est, t_est, R_gt, t_gt),
            1,
        ),
        (
            "adds_batch (workers=2)",
            setup,
            lambda: adds_batch(pts, R_est, t_est, R_gt, t_gt, workers=2),
            1,
        ),
        ("add_batch", setup, lambda: add_batch(pts, R_est, t_est, R_gt, t_gt), 1),
    ]
    grid = RotationGrid.uniform(20000)
    queries = random_rotations(50, rng)
    rows.append(("RotationGrid.nearest", "N=50 vs K=20000", lambda: grid.nearest(queries), 100))
    out = []
    for name, desc, fn, calls in rows:
        seconds = _median_seconds(fn, runs, calls)
        out.append({"name": name, "setup": desc, "median_ms": seconds * 1e3, "runs": runs})
    return out


def format_table(rows: list[dict]) -> str:
    """Plain-text table of run()'s rows."""
    lines = [f"{'benchmark':<24} {'setup':<28} {'median ms':>10}", "-" * 64]
    lines += [f"{r['name']:<24} {r['setup']:<28} {r['median_ms']:>10.2f}" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark table; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="timed runs per row (median)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(format_table(run(runs=args.runs, seed=args.seed)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
