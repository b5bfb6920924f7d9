"""Pose error metrics of the YCB-Video and BOP conventions: ADD, ADD-S (metres), the VOCap
AUC and the accuracy at a threshold (BOP's "ADD(-S) < 0.1 d").

Poses map object to camera: x_cam = R @ x_obj + t; points are model points (M, 3) in metres.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["accuracy", "add", "add_batch", "adds", "adds_batch", "auc"]

# Number of (pose, point) pairs transformed at once by the batched metrics (bounds memory).
_CHUNK_PAIRS = 1 << 19


def _check_points(points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 1:
        raise ValueError(f"metrics: expected model points (M, 3) with M >= 1, got {points.shape}")
    return points


def _check_poses(
    R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    R_est = np.asarray(R_est, dtype=np.float64)
    t_est = np.asarray(t_est, dtype=np.float64)
    R_gt = np.asarray(R_gt, dtype=np.float64)
    t_gt = np.asarray(t_gt, dtype=np.float64)
    p = R_est.shape[0] if R_est.ndim == 3 else -1
    ok = (
        p >= 0
        and R_est.shape == (p, 3, 3)
        and R_gt.shape == (p, 3, 3)
        and t_est.shape == (p, 3)
        and t_gt.shape == (p, 3)
    )
    if not ok:
        raise ValueError(
            "metrics: expected R_est, R_gt (P, 3, 3) and t_est, t_gt (P, 3), got "
            f"{R_est.shape}, {t_est.shape}, {R_gt.shape}, {t_gt.shape}"
        )
    return R_est, t_est, R_gt, t_gt


def _chunk_step(num_points: int) -> int:
    """Poses per chunk so that a chunk holds about _CHUNK_PAIRS (pose, point) pairs."""
    return max(1, _CHUNK_PAIRS // num_points)


def add_batch(
    points: np.ndarray, R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray
) -> np.ndarray:
    """ADD (P,) in metres: mean_i |(R_e m_i + t_e) - (R_g m_i + t_g)| for P pose pairs.

    points (M, 3) m; R_est, R_gt (P, 3, 3); t_est, t_gt (P, 3) m.
    """
    points = _check_points(points)
    R_est, t_est, R_gt, t_gt = _check_poses(R_est, t_est, R_gt, t_gt)
    num_poses, m = R_est.shape[0], points.shape[0]
    dR = R_est - R_gt
    dt = t_est - t_gt
    out = np.empty(num_poses, dtype=np.float64)
    step = _chunk_step(m)
    for s in range(0, num_poses, step):
        diff = np.matmul(points, np.swapaxes(dR[s : s + step], 1, 2)) + dt[s : s + step, None, :]
        out[s : s + step] = np.sqrt(np.einsum("pmi,pmi->pm", diff, diff)).mean(axis=1)
    return out


def adds_batch(
    points: np.ndarray,
    R_est: np.ndarray,
    t_est: np.ndarray,
    R_gt: np.ndarray,
    t_gt: np.ndarray,
    *,
    workers: int = 1,
) -> np.ndarray:
    """ADD-S (P,) in metres: mean over gt-posed points of the distance to the nearest
    estimate-posed point, for P pose pairs.

    Distances are invariant under rigid motion, so each gt-posed point is brought into the
    estimate's object frame, y_i = R_e^T (R_g m_i + t_g - t_e), and
    ADD-S = mean_i min_j |m_j - y_i|: one KD-tree of the model points serves all poses.
    points (M, 3) m; R_est, R_gt (P, 3, 3); t_est, t_gt (P, 3) m; workers: threads of the
    KD-tree queries (scipy convention, -1 = all cores).
    """
    points = _check_points(points)
    R_est, t_est, R_gt, t_gt = _check_poses(R_est, t_est, R_gt, t_gt)
    num_poses, m = R_est.shape[0], points.shape[0]
    R_rel = np.swapaxes(R_est, 1, 2) @ R_gt  # (P, 3, 3)
    t_rel = np.einsum("pji,pj->pi", R_est, t_gt - t_est)  # R_e^T (t_g - t_e), (P, 3)
    tree = cKDTree(points)
    # Queries in the tree's leaf order are more cache friendly; the mean does not depend on it.
    pts = points[tree.indices]
    out = np.empty(num_poses, dtype=np.float64)
    step = _chunk_step(m)
    for s in range(0, num_poses, step):
        y = np.matmul(pts, np.swapaxes(R_rel[s : s + step], 1, 2)) + t_rel[s : s + step, None, :]
        dist, _ = tree.query(y.reshape(-1, 3), k=1, workers=workers)
        out[s : s + step] = dist.reshape(-1, m).mean(axis=1)
    return out


def _one_pair(batch_fn: Callable[..., np.ndarray], points: np.ndarray, *pose: np.ndarray) -> float:
    """``batch_fn(points, R_est, t_est, R_gt, t_gt)`` of one pose pair (R (3, 3), t (3,) m)."""
    return float(batch_fn(points, *(np.asarray(a, dtype=np.float64)[None] for a in pose))[0])


def add(
    points: np.ndarray, R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray
) -> float:
    """ADD (metres) of one pose pair; points (M, 3) m, R (3, 3), t (3,) m."""
    return _one_pair(add_batch, points, R_est, t_est, R_gt, t_gt)


def adds(
    points: np.ndarray, R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray
) -> float:
    """ADD-S (metres) of one pose pair (KD-tree nearest neighbour); points (M, 3) m."""
    return _one_pair(adds_batch, points, R_est, t_est, R_gt, t_gt)


def auc(errors: np.ndarray, max_threshold: float = 0.1) -> float:
    """Area under the accuracy-threshold curve from 0 to max_threshold, in percent (0..100).

    The VOCap rule of the YCB-Video toolbox: errors above the threshold count as failures;
    missing estimates (nan or inf) stay in the count n; the accuracy at the i-th smallest
    error is i / n; with mrec = [0, d_1..d_k, max_threshold] and mpre = [0, i/n..., k/n]
    (made non-decreasing), AUC = 100 / max_threshold * sum over the points where mrec
    changes of (mrec[i] - mrec[i-1]) * mpre[i]. Empty input or no success gives 0.0.
    errors: (n,) metres (any shape is flattened).
    """
    if not max_threshold > 0:
        raise ValueError(f"auc: max_threshold must be > 0, got {max_threshold}")
    d = np.array(errors, dtype=np.float64).reshape(-1)
    n = d.size
    if n == 0:
        return 0.0
    if np.any(d < 0):
        raise ValueError("auc: errors must be >= 0 (nan or inf mark missing estimates)")
    with np.errstate(invalid="ignore"):
        d[d > max_threshold] = np.inf
    d = np.sort(d)  # inf and nan go last
    prec = np.arange(1, n + 1, dtype=np.float64) / n
    finite = np.isfinite(d)
    rec = d[finite]
    if rec.size == 0:
        return 0.0
    prec = prec[finite]
    mrec = np.concatenate([[0.0], rec, [max_threshold]])
    mpre = np.maximum.accumulate(np.concatenate([[0.0], prec, [prec[-1]]]))
    idx = np.flatnonzero(mrec[1:] != mrec[:-1]) + 1
    area = np.sum((mrec[idx] - mrec[idx - 1]) * mpre[idx])
    return float(area / max_threshold * 100.0)


def accuracy(errors: np.ndarray, thresholds: np.ndarray | float) -> float:
    """Share in percent (0..100) of the errors below their threshold (error < threshold).

    errors (n,) metres, nan or inf for a missing estimate (a failure); thresholds: one value
    or (n,) per error (e.g. 0.1 x each object's diameter). Empty input gives 0.0.
    """
    d = np.asarray(errors, dtype=np.float64).reshape(-1)
    if d.size == 0:
        return 0.0
    thr = np.broadcast_to(np.asarray(thresholds, dtype=np.float64), d.shape)
    with np.errstate(invalid="ignore"):
        ok = d < thr
    return float(100.0 * np.count_nonzero(ok) / d.size)
