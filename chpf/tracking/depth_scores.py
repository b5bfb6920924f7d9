"""Depth scores of pose hypotheses from codebook depth crops (no rendering at run time).

For a hypothesis at translation t = (x, y, z) whose orientation has codebook entry k, the
rendered depth crop is the codebook depth crop of k (object at distance D_r) shifted to the
particle: rendered = crop_depth - D_r + z on the object's pixels. It is compared pixel by
pixel with the measured depth sampled on the particle's crop (nearest neighbour, so holes
stay holes). Only pixels where both are valid count.

- L_depth: fraction of those pixels with |measured - rendered| < ``margin`` (PoseRBPF: 0.03 m).
- C_depth: fraction of those pixels where measured > rendered + ``c_margin`` (the sensor sees
  behind the hypothesised surface: impossible if the pose were right, whereas measured <
  rendered is explained by an occluder).

With no valid pixel (object off the image, all holes) both are ``no_data``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class DepthScores:
    """L_depth (N,) and C_depth (N,) in [0, 1]; ``valid`` (N,) count of compared pixels."""

    L: np.ndarray
    C: np.ndarray
    valid: np.ndarray


def depth_scores(
    measured: np.ndarray,
    crop_depth: np.ndarray,
    z: np.ndarray,
    render_distance: float,
    margin: float = 0.03,
    c_margin: float = 0.02,
    no_data: float = 0.5,
) -> DepthScores:
    """Scores from measured depth crops (N,Sd,Sd) m (0 = hole), codebook depth crops (N,Sd,Sd)
    m at ``render_distance`` (0 = empty) and particle depths z (N,) m (see module docstring)."""
    meas = np.asarray(measured, dtype=np.float32)
    cb = np.asarray(crop_depth, dtype=np.float32)
    shift = (np.asarray(z, dtype=np.float32) - np.float32(render_distance))[:, None, None]
    rendered = cb + shift
    valid = (cb > 0) & (meas > 0)
    diff = meas - rendered
    n_valid = valid.sum(axis=(1, 2))
    n_close = (valid & (np.abs(diff) < margin)).sum(axis=(1, 2))
    n_behind = (valid & (diff > c_margin)).sum(axis=(1, 2))
    has = n_valid > 0
    denom = np.maximum(n_valid, 1)
    L = np.where(has, n_close / denom, no_data)
    C = np.where(has, n_behind / denom, no_data)
    return DepthScores(L=L.astype(np.float64), C=C.astype(np.float64), valid=n_valid)
