"""Figures of a bench run with 95 % bootstrap confidence intervals over sequences.

A cell (method x modality x occlusion level or all, frames all or occluded) holds, per seed,
the frames of each of its sequences. Its value is the mean over seeds of a statistic of the
pooled frames (e.g. the ADD-S AUC pooled over instances, the YCB-Video convention); its
interval: the 2.5 and 97.5 percentiles of that value over ``B`` resamples of the sequences
with replacement (the same resample for every seed), seeded so that a report is reproducible.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from chpf.metrics import accuracy, auc

OCCLUDED_BELOW = 0.75
"""A frame is occluded when less than this fraction of the target is visible (visib_fract)."""
TRACKED_BELOW = 0.1
"""A frame is tracked when its ADD-S error is below this fraction of the diameter."""
LOST_ABOVE = 0.5
"""A frame is lost when its ADD-S error is above this fraction of the diameter."""
HIDDEN_BELOW = 0.3
"""A frame is mostly hidden when less than this fraction of the target is visible."""

Statistic = Callable[[np.ndarray, np.ndarray], float]
"""(errors (n,) m, diameters (n,) m) -> a figure."""


def auc_stat(errors: np.ndarray, diameters: np.ndarray) -> float:
    """VOCap AUC 0-10 cm (percent) of the pooled errors."""
    return auc(errors)


def tracked_stat(errors: np.ndarray, diameters: np.ndarray) -> float:
    """Share of frames (percent) with error below TRACKED_BELOW x diameter."""
    return accuracy(errors, TRACKED_BELOW * diameters)


@dataclass
class Estimate:
    """A figure with its 95 % interval; n_sequences, n_frames: what it was computed from."""

    value: float
    lo: float
    hi: float
    n_sequences: int
    n_frames: int


def bootstrap(
    per_seed: list[list[tuple[np.ndarray, np.ndarray]]],
    stat: Statistic,
    resamples: int,
    seed: int = 0,
) -> Estimate:
    """``per_seed[s][q]``: (errors, diameters) of sequence q under seed s (same q order for
    every seed). Value: mean over seeds of stat(pooled frames); 95 % interval over resampled
    sequences. A cell without frames gives nan."""
    n_seq = len(per_seed[0]) if per_seed else 0
    n_frames = sum(len(e) for seq in per_seed for e, _ in seq)
    if n_seq == 0 or n_frames == 0:
        return Estimate(float("nan"), float("nan"), float("nan"), n_seq, n_frames)

    def value(idx: np.ndarray) -> float:
        vals = []
        for seqs in per_seed:
            e = np.concatenate([seqs[i][0] for i in idx])
            d = np.concatenate([seqs[i][1] for i in idx])
            vals.append(stat(e, d) if len(e) else np.nan)
        return float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")

    point = value(np.arange(n_seq))
    rng = np.random.default_rng(seed)
    boots = np.array([value(rng.integers(0, n_seq, n_seq)) for _ in range(resamples)])
    boots = boots[np.isfinite(boots)]
    lo, hi = np.percentile(boots, [2.5, 97.5]) if len(boots) else (np.nan, np.nan)
    return Estimate(point, float(lo), float(hi), n_seq, n_frames // len(per_seed))


def reacquisition(tracked: np.ndarray) -> tuple[list[int], int]:
    """Frames from each loss (tracked -> not tracked) to the next tracked frame, and the number
    of losses never recovered before the end. tracked: (F,) bool per frame."""
    times, open_losses = [], 0
    lost_at = None
    for k in range(1, len(tracked)):
        if tracked[k - 1] and not tracked[k]:
            lost_at = k
        elif lost_at is not None and tracked[k]:
            times.append(k - lost_at)
            lost_at = None
    if lost_at is not None:
        open_losses += 1
    return times, open_losses
