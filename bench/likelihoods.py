"""The likelihoods at the true pose on a bench run's sequences, by visibility band.

Scores every ground-truth instance of the tracked object (its visible box as the detection) with
the bundle's L and C at the true pose: on a suite of the held-out family this says whether the
Counter-Hypothetical classifier keeps calling an aligned but occluded object aligned under
occluders and backgrounds that training never drew (C < 0.5 counts as "aligned").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench.report import csv_text, md_table
from bench.sequences import Sequence
from chpf.atomic import atomic_write_text
from chpf.bop import BopDataset
from chpf.bundle import Bundle
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import Frame

BANDS: tuple[tuple[float, float], ...] = ((0.9, 1.0), (0.6, 0.9), (0.3, 0.6), (0.0, 0.3))
"""Visible-fraction bands [low, high) (the top one includes 1)."""

ALIGNED_BELOW = 0.5
HEADER = ("bundle", "band", "frames", "mean_C", "aligned_pct", "mean_L")


def truth_scores(seqs: list[Sequence]) -> dict[str, np.ndarray]:
    """Per bundle path, an (n, 3) array of (visible fraction, C, L) at the true pose, one row per
    instance of the bundle's object with a visible box."""
    likelihoods: dict[str, Any] = {}
    rows: dict[str, list[tuple[float, float, float]]] = {}
    for seq in seqs:
        if seq.bundle not in likelihoods:
            likelihoods[seq.bundle] = Tracker.from_bundle(Bundle.load(seq.bundle)).likelihood
        scene = BopDataset(seq.root).scene("test", seq.scene_id)
        for im in scene.image_ids():
            for gt, info in zip(scene.gt[im], scene.gt_info[im], strict=True):
                if gt.obj_id != seq.obj_id or info.bbox_visib[2] <= 0:
                    continue
                frame = Frame(
                    rgb=scene.rgb(im),
                    depth=None,
                    K=scene.camera(im).K,
                    box=np.asarray(info.bbox_visib, dtype=np.float64),
                )
                s = likelihoods[seq.bundle].score(frame, gt.R[None], gt.t[None])
                rows.setdefault(seq.bundle, []).append(
                    (info.visib_fract, float(s.C[0]), float(s.L[0]))
                )
    return {b: np.asarray(r, dtype=np.float64) for b, r in rows.items()}


def band_rows(scores: dict[str, np.ndarray]) -> list[tuple[Any, ...]]:
    """HEADER rows: per bundle and visibility band, frames, mean C, % aligned, mean L."""
    out = []
    for bundle, s in scores.items():
        for lo, hi in BANDS:
            k = (s[:, 0] >= lo) & ((s[:, 0] < hi) | (hi == 1.0))
            if not k.any():
                continue
            c, lik = s[k, 1], s[k, 2]
            out.append(
                (
                    bundle,
                    f"{lo:.0%}-{hi:.0%}",
                    int(k.sum()),
                    round(float(c.mean()), 3),
                    round(100.0 * float(np.mean(c < ALIGNED_BELOW)), 1),
                    round(float(lik.mean()), 3),
                )
            )
    return out


def write_likelihoods(out: Path, seqs: list[Sequence]) -> str:
    """Score ``seqs``, write ``out/report/likelihoods.{csv,md}``; the markdown table."""
    rows = band_rows(truth_scores(seqs))
    table = md_table(list(HEADER), [[str(v) for v in r] for r in rows])
    folder = out / "report"
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_text(folder / "likelihoods.csv", csv_text([list(r) for r in rows], list(HEADER)))
    atomic_write_text(
        folder / "likelihoods.md",
        "# L and C at the true pose, by visible fraction\n\n" + table + "\n",
    )
    return table
