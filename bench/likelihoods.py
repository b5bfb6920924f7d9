"""The likelihoods at and near the true pose on a bench run's sequences, by visibility band.

Scores every ground-truth instance of the tracked object (its visible box as the detection) with
the bundle's L and C at the true pose: on a suite of the held-out family this says whether the
Counter-Hypothetical classifier keeps calling an aligned but occluded object aligned under
occluders and backgrounds that training never drew (C < 0.5 counts as "aligned"). It also
scores NEAR poses per instance, each turned by up to NEAR_DEG about a random axis and moved by
up to NEAR_SHIFT diameters (so within 0.1 diameters of the truth by ADD): the C a tracked
particle has, whose rise with occlusion is what drives a CH-PF's alpha up under occlusion.
C is the classifier's with the default config's box scale, without the silhouette's
(``chpf.c_silhouette``): that one measures a pose against the others scored with it, here the
truth against its own near poses.
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
from chpf.geometry import axis_angle_to_matrix
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import Frame

BANDS: tuple[tuple[float, float], ...] = ((0.9, 1.0), (0.6, 0.9), (0.3, 0.6), (0.0, 0.3))
"""Visible-fraction bands [low, high) (the top one includes 1)."""

ALIGNED_BELOW = 0.5
HEADER = ("bundle", "band", "frames", "mean_C", "aligned_pct", "mean_L", "mean_C_near")
NEAR = 8
"""Poses near the truth scored per instance."""
NEAR_DEG = 5.0
"""Their largest turn (degrees) ..."""
NEAR_SHIFT = 0.03
"""... and shift (diameters): at most 0.03 + 0.5 * 5 deg in rad = 0.074 diameters by ADD."""


def near_poses(
    R: np.ndarray, t: np.ndarray, diameter: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """NEAR poses (R (NEAR,3,3), t (NEAR,3)) around (R, t): turned by up to NEAR_DEG about a
    random axis (in the camera frame), shifted by up to NEAR_SHIFT diameters."""
    axes = rng.normal(size=(NEAR, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    turns = axis_angle_to_matrix(axes * np.radians(rng.uniform(0.0, NEAR_DEG, (NEAR, 1))))
    dirs = rng.normal(size=(NEAR, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    shifts = dirs * rng.uniform(0.0, NEAR_SHIFT * diameter, (NEAR, 1))
    return turns @ R, t + shifts


def truth_scores(seqs: list[Sequence]) -> dict[str, np.ndarray]:
    """Per bundle path, an (n, 4) array of (visible fraction, C, L at the true pose, mean C of
    the near poses), one row per instance of the bundle's object with a visible box."""
    likelihoods: dict[str, Any] = {}
    diameters: dict[str, float] = {}
    rows: dict[str, list[tuple[float, float, float, float]]] = {}
    rng = np.random.default_rng(0)
    for seq in seqs:
        if seq.bundle not in likelihoods:
            bundle = Bundle.load(seq.bundle)
            # the classifier's C (with the box scale), not the silhouette's, which ranks a pose
            # among those scored with it (here the truth and its near poses)
            likelihoods[seq.bundle] = Tracker.from_bundle(
                bundle, chpf={"c_silhouette": None}
            ).likelihood
            diameters[seq.bundle] = bundle.obj_info.diameter
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
                R_near, t_near = near_poses(gt.R, gt.t, diameters[seq.bundle], rng)
                R_all = np.concatenate([gt.R[None], R_near])
                s = likelihoods[seq.bundle].score(
                    frame, R_all, np.concatenate([gt.t[None], t_near])
                )
                rows.setdefault(seq.bundle, []).append(
                    (info.visib_fract, float(s.C[0]), float(s.L[0]), float(s.C[1:].mean()))
                )
    return {b: np.asarray(r, dtype=np.float64) for b, r in rows.items()}


def band_index(visib: float) -> int:
    """Index into BANDS of a visible fraction in [0, 1]."""
    return next(i for i, (lo, hi) in enumerate(BANDS) if lo <= visib < hi or visib >= hi == 1.0)


def band_rows(scores: dict[str, np.ndarray]) -> list[tuple[Any, ...]]:
    """HEADER rows: per bundle and visibility band, frames, mean C, % aligned, mean L (at the
    truth), mean C of the near poses."""
    out = []
    for bundle, s in scores.items():
        bands = np.array([band_index(v) for v in s[:, 0]])
        for i, (lo, hi) in enumerate(BANDS):
            k = bands == i
            if not k.any():
                continue
            c, lik, near = s[k, 1], s[k, 2], s[k, 3]
            out.append(
                (
                    bundle,
                    f"{lo:.0%}-{hi:.0%}",
                    int(k.sum()),
                    round(float(c.mean()), 3),
                    round(100.0 * float(np.mean(c < ALIGNED_BELOW)), 1),
                    round(float(lik.mean()), 3),
                    round(float(near.mean()), 3),
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
        "# L and C at the true pose, by visible fraction\n\n"
        f"mean_C_near: C of {NEAR} poses per frame within {NEAR_DEG:g} deg and "
        f"{NEAR_SHIFT:g} diameters of the truth.\n\n" + table + "\n",
    )
    return table
