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
