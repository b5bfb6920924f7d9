"""Sparse diffusion of probability vectors over a rotation grid (PoseRBPF's rotation prior)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from chpf.geometry import RotationGrid


def grid_spacing(grid: RotationGrid) -> float:
    """Median angle (rad) between each grid entry and its nearest other entry."""
    if len(grid) < 2:
        return np.pi
    q = grid.quats
    tree = cKDTree(np.concatenate([q, -q]))
    d, _ = tree.query(q, k=3)  # self, then the nearest other (either sign)
    chord = d[:, 1]
    return float(np.median(4.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0))))


def _nearest_entries(grid: RotationGrid, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest grid entries of every entry, itself first: indices (K,k) and geodesic
    angles (K,k) rad, sorted by angle (fewer than k where the grid is smaller)."""
    n = len(grid)
    k = int(min(max(k, 1), n))
    q = grid.quats
    tree = cKDTree(np.concatenate([q, -q]))
    d, idx = tree.query(q, k=min(2 * k, 2 * n))
    idx = idx.reshape(n, -1) % n
    theta = 4.0 * np.arcsin(np.clip(d.reshape(n, -1) / 2.0, 0.0, 1.0))  # chord = 2 sin(theta/4)
    # Both signs of an entry may appear among the 2k queried: keep each entry's first (nearest).
    out_idx = np.empty((n, k), dtype=np.int64)
    out_theta = np.empty((n, k))
    for row in range(n):
        _, first = np.unique(idx[row], return_index=True)
        keep = np.sort(first)[:k]
        out_idx[row], out_theta[row] = idx[row, keep], theta[row, keep]
    return out_idx, out_theta


def neighbour_table(grid: RotationGrid, k: int) -> np.ndarray:
    """Indices (K,k) of the k nearest grid entries of every entry (itself first)."""
    return _nearest_entries(grid, k)[0]


def neighbour_matrix(grid: RotationGrid, k: int = 12, sigma: float | None = None) -> sp.csr_matrix:
    """Row-stochastic sparse (K,K) matrix D: row j spreads entry j's mass over its k nearest
    grid entries (itself included) with a Gaussian kernel exp(-theta^2 / (2 sigma^2)) in the
    geodesic angle theta (rad). sigma None = the grid spacing. A distribution p (.., K) over the
    grid diffuses as p @ D."""
    n = len(grid)
    if sigma is None:
        sigma = grid_spacing(grid)
    idx, theta = _nearest_entries(grid, k)
    vals = np.exp(-0.5 * (theta / max(sigma, 1e-9)) ** 2)
    rows = np.repeat(np.arange(n), idx.shape[1])
    D = sp.csr_matrix((vals.ravel(), (rows, idx.ravel())), shape=(n, n))
    s = np.asarray(D.sum(axis=1)).ravel()
    return sp.csr_matrix(sp.diags(1.0 / s) @ D)
