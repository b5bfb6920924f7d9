"""Validation metrics in numpy: ROC AUC, symmetry-aware rotation errors, codebook retrieval."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def band_label(lo: float, hi: float | None) -> str:
    """``lo-hi`` of a band of figures, ``lo+`` of an open one (``hi`` None)."""
    return f"{lo:g}+" if hi is None else f"{lo:g}-{hi:g}"


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for binary ``labels`` (1 = positive class).

    Mann-Whitney form with average ranks, so ties count one half:
    AUC = P(score_pos > score_neg) + 0.5 P(score_pos == score_neg). nan if a class is empty.
    """
    s = np.asarray(scores, dtype=np.float64).ravel()
    y = np.asarray(labels).ravel().astype(bool)
    if s.shape != y.shape:
        raise ValueError(f"roc_auc: scores {s.shape} and labels {y.shape} differ in shape")
    n_pos = int(y.sum())
    n_neg = y.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    s_sorted = s[order]
    # average rank (1-based) of each tie group
    starts = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    ends = np.r_[starts[1:], s.size]
    group_rank = (starts + 1 + ends) / 2.0
    ranks = np.empty(s.size, dtype=np.float64)
    ranks[order] = np.repeat(group_rank, ends - starts)
    u = ranks[y].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


def roc_auc_interval(
    scores: np.ndarray, labels: np.ndarray, resamples: int = 1000, seed: int = 0
) -> tuple[float, float]:
    """95 % bootstrap interval (lo, hi) of ``roc_auc(scores, labels)``: the 2.5 and 97.5
    percentiles over ``resamples`` draws of the positives and of the negatives, each with
    replacement and at its own count (stratified), seeded so that a report is reproducible.
    (nan, nan) if a class is empty."""
    s = np.asarray(scores, dtype=np.float64).ravel()
    y = np.asarray(labels).ravel().astype(bool)
    pos, neg = np.flatnonzero(y), np.flatnonzero(~y)
    if pos.size == 0 or neg.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    truth = np.r_[np.ones(pos.size, bool), np.zeros(neg.size, bool)]
    boots = [
        roc_auc(s[np.r_[rng.choice(pos, pos.size), rng.choice(neg, neg.size)]], truth)
        for _ in range(resamples)
    ]
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(lo), float(hi)


def _angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between unit vectors along the last axis."""
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


def _geodesic(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    tr = np.einsum("...ij,...ij->...", R1, R2)  # trace(R1^T R2)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def symmetry_aware_angle(
    R_est: np.ndarray,
    R_gt: np.ndarray,
    symmetries_discrete: Sequence[np.ndarray] | np.ndarray | None = None,
    symmetries_continuous: Sequence[dict] | None = None,
) -> np.ndarray:
    """Rotation error (rad) ``(N,)`` between ``R_est`` and ``R_gt`` ``(N,3,3)`` up to symmetry.

    Discrete symmetries (BOP 4x4, translation ignored) give ``min_s angle(R_est, R_gt S_s)``
    (identity included). One continuous axis ``a`` gives the axis-aware angle
    ``min_s angle(R_est a, R_gt S_s a)`` -- the exact distance to the set of rotations that differ
    by a spin about ``a``. Two or more continuous axes (a sphere): zero.
    """
    R_est = np.asarray(R_est, dtype=np.float64).reshape(-1, 3, 3)
    R_gt = np.asarray(R_gt, dtype=np.float64).reshape(-1, 3, 3)
    syms = [np.eye(3)]
    for S in symmetries_discrete if symmetries_discrete is not None else []:
        syms.append(np.asarray(S, dtype=np.float64).reshape(4, 4)[:3, :3])
    S_all = np.stack(syms)  # (M,3,3)
    R_gt_s = np.einsum("nij,mjk->nmik", R_gt, S_all)  # (N,M,3,3)
    cont = list(symmetries_continuous or [])
    if len(cont) >= 2:
        return np.zeros(R_est.shape[0])
    if len(cont) == 1:
        axis = np.asarray(cont[0]["axis"], dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        a_est = R_est @ axis  # (N,3)
        a_gt = R_gt_s @ axis  # (N,M,3)
        return _angle_between(a_est[:, None, :], a_gt).min(axis=1)
    return _geodesic(R_est[:, None], R_gt_s).min(axis=1)


def cosine_retrieval(
    query: np.ndarray, codebook: np.ndarray, chunk: int = 1024
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest codebook entry by cosine: ``(index (N,), cosine (N,))`` for (N,E) vs (K,E)."""
    q = np.asarray(query, dtype=np.float32)
    c = np.asarray(codebook, dtype=np.float32)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    c = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
    idx = np.empty(q.shape[0], dtype=np.int64)
    cos = np.empty(q.shape[0], dtype=np.float32)
    for i in range(0, q.shape[0], chunk):
        sim = q[i : i + chunk] @ c.T
        j = sim.argmax(axis=1)
        idx[i : i + chunk] = j
        cos[i : i + chunk] = sim[np.arange(j.size), j]
    return idx, cos


def retrieval_summary(errors_deg: np.ndarray, threshold_deg: float = 30.0) -> dict[str, float]:
    """``{"median_deg", "mean_deg", "pct_below"}`` of retrieval errors in degrees."""
    e = np.asarray(errors_deg, dtype=np.float64)
    if e.size == 0:
        return {"median_deg": float("nan"), "mean_deg": float("nan"), "pct_below": float("nan")}
    return {
        "median_deg": float(np.median(e)),
        "mean_deg": float(e.mean()),
        "pct_below": float(100.0 * np.mean(e < threshold_deg)),
    }
