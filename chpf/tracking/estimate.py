"""Point estimate of a weighted particle set."""

from __future__ import annotations

import numpy as np

from chpf.geometry import average_quaternions, matrix_to_quat, quat_to_matrix


def weighted_pose(R: np.ndarray, t: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean translation (3,) and weighted quaternion average rotation (3,3)
    (eigenvector method) of poses R (N,3,3), t (N,3) with normalised weights w (N,)."""
    t_est = np.asarray(w, dtype=np.float64) @ np.asarray(t, dtype=np.float64)
    q_est = average_quaternions(matrix_to_quat(R), w)
    return quat_to_matrix(q_est), t_est
