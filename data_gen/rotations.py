"""Rotation helpers for sample labels: symmetry-aware angles, candidate draws, grid spacing."""

from __future__ import annotations

import numpy as np

from chpf.geometry import (
    RotationGrid,
    axis_angle_to_matrix,
    geodesic_angle,
    matrix_to_quat,
    random_rotations,
)


def symmetry_set(
    symmetries_discrete: list, symmetries_continuous: list
) -> tuple[np.ndarray, np.ndarray]:
    """(G,3,3) discrete symmetry rotations incl. identity and (A,3) unit continuous axes."""
    rots = [np.eye(3)]
    for T in symmetries_discrete:
        R = np.asarray(T, dtype=np.float64)[:3, :3]
        if not np.allclose(R, np.eye(3), atol=1e-6):
            rots.append(R)
    axes = [np.asarray(s["axis"], np.float64) for s in symmetries_continuous]
    axes = [a / np.linalg.norm(a) for a in axes if np.linalg.norm(a) > 0]
    return np.stack(rots), (np.stack(axes) if axes else np.zeros((0, 3)))


def symmetric_angle(
    R1: np.ndarray, R2: np.ndarray, sym_rots: np.ndarray, sym_axes: np.ndarray
) -> np.ndarray:
    """Smallest angle (rad) between R1 and R2 @ S over the object symmetries S; R (N,3,3).

    Discrete: min over ``sym_rots`` (G,3,3). Continuous axis a: the best rotation about a is
    found in closed form: with q = (w, v) the quaternion of S_g^T R2^T R1, the angle is
    2 acos(sqrt(w^2 + (a.v)^2)) (minimum over the first continuous axis; objects have one).
    """
    R1 = np.asarray(R1, np.float64)
    R2 = np.asarray(R2, np.float64)
    Q = np.swapaxes(R2, -1, -2) @ R1  # (N,3,3)
    best = np.full(Q.shape[0], np.inf)
    for S in sym_rots:
        Qg = S.T @ Q
        if len(sym_axes):
            q = matrix_to_quat(Qg)
            c = np.sqrt(q[:, 0] ** 2 + (q[:, 1:] @ sym_axes[0]) ** 2)
            ang = 2.0 * np.arccos(np.clip(c, 0.0, 1.0))
        else:
            ang = geodesic_angle(np.eye(3), Qg)
        best = np.minimum(best, ang)
    return best


def rotations_at_angle(R: np.ndarray, lo: float, hi: float, rng: np.random.Generator) -> np.ndarray:
    """exp(w) @ R with a uniform random axis and |w| uniform in [lo, hi] rad; R (N,3,3)."""
    n = R.shape[0]
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ang = rng.uniform(lo, hi, n)
    return axis_angle_to_matrix(axis * ang[:, None]) @ R


def half_turns(R: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """R @ H with H a half turn about the x, y or z axis of the object (one drawn per row):
    the object upside down or turned back to front, the look-alikes of many objects (a mug's
    open top and its base). R (N,3,3) object -> camera."""
    flips = np.stack([np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1])])
    return np.asarray(R, np.float64) @ flips[rng.integers(0, 3, len(R))]


def perturb_bounded(
    R: np.ndarray, sigma: float, max_angle: float, rng: np.random.Generator
) -> np.ndarray:
    """exp(w) @ R with w ~ N(0, sigma^2 I), redrawn while |w| > max_angle (rad)."""
    n = R.shape[0]
    w = rng.standard_normal((n, 3)) * sigma
    for _ in range(100):
        bad = np.linalg.norm(w, axis=1) > max_angle
        if not bad.any():
            break
        w[bad] = rng.standard_normal((int(bad.sum()), 3)) * sigma
    else:  # sigma >> max_angle: shrink the stubborn ones onto the bound
        norm = np.linalg.norm(w, axis=1, keepdims=True)
        w = np.where(norm > max_angle, w / norm * max_angle, w)
    return axis_angle_to_matrix(w) @ R


def draw_candidates(
    grid: RotationGrid,
    R_true: np.ndarray,
    aligned: np.ndarray,
    p: dict,
    sym_rots: np.ndarray,
    sym_axes: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Codebook indices (N,) of ``grid`` and symmetry-aware angles (N,) rad of hypotheses for
    true allocentric rotations R_true (N,3,3), drawn as the ``pairs`` config ``p`` says:
    positives (aligned=1) near R_true, negatives at least ``neg_min_angle_deg`` away (hard ones
    drawn at ``hard_negative_range_deg``, flips as half turns about an object axis perturbed
    like positives). Symmetries: ``symmetry_set``."""
    n = len(R_true)
    idx = np.empty(n, np.int64)
    pos = aligned.astype(bool)
    if pos.any():
        Rh = perturb_bounded(
            R_true[pos],
            np.radians(p["pos_rot_sigma_deg"]),
            np.radians(p["pos_rot_max_deg"]),
            rng,
        )
        idx[pos] = grid.nearest(Rh)
    neg = np.flatnonzero(~pos)
    kind = rng.random(len(neg))
    hard = kind < p["hard_negative_share"]
    flip = ~hard & (kind < p["hard_negative_share"] + p["flip_negative_share"])
    lo, hi = np.radians(p["hard_negative_range_deg"])
    pos_sigma, pos_max = np.radians([p["pos_rot_sigma_deg"], p["pos_rot_max_deg"]])
    min_ang = np.radians(p["neg_min_angle_deg"])
    todo = np.ones(len(neg), bool)
    for it in range(200):
        if not todo.any():
            break
        sel = neg[todo]
        # give up on hard and flip draws that keep snapping too close (symmetric objects)
        h, f = hard[todo] & (it < 100), flip[todo] & (it < 100)
        Rh = random_rotations(len(sel), rng)
        if h.any():
            Rh[h] = rotations_at_angle(R_true[sel[h]], lo, hi, rng)
        if f.any():
            Rh[f] = perturb_bounded(half_turns(R_true[sel[f]], rng), pos_sigma, pos_max, rng)
        idx[sel] = grid.nearest(Rh)
        ang = symmetric_angle(R_true[sel], grid.rotations[idx[sel]], sym_rots, sym_axes)
        todo[np.flatnonzero(todo)[ang >= min_ang]] = False
    if todo.any():
        raise RuntimeError("could not draw negatives far enough from the true orientation")
    ang = symmetric_angle(R_true, grid.rotations[idx], sym_rots, sym_axes)
    return idx, ang


def grid_spacing_deg(grid: RotationGrid, n: int = 20000, seed: int = 0) -> dict[str, float]:
    """Angle (deg) from random rotations to their nearest grid entry: median, p99 and max of a
    seeded sample of ``n`` (the covering radius is close to the max)."""
    R = random_rotations(n, np.random.default_rng(seed))
    ang = np.degrees(geodesic_angle(R, grid.rotations[grid.nearest(R)]))
    return {
        "median": round(float(np.median(ang)), 3),
        "p99": round(float(np.percentile(ang, 99)), 3),
        "max": round(float(ang.max()), 3),
    }
