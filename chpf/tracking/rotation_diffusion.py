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


def neighbour_matrix(grid: RotationGrid, k: int = 12, sigma: float | None = None) -> sp.csr_matrix:
    """Row-stochastic sparse (K,K) matrix D: row j spreads entry j's mass over its k nearest
    grid entries (itself included) with a Gaussian kernel exp(-theta^2 / (2 sigma^2)) in the
    geodesic angle theta (rad). sigma None = the grid spacing. A distribution p (.., K) over the
    grid diffuses as p @ D."""
    n = len(grid)
    k = int(min(max(k, 1), n))
    q = grid.quats
    if sigma is None:
        sigma = grid_spacing(grid)
    tree = cKDTree(np.concatenate([q, -q]))
    d, idx = tree.query(q, k=min(2 * k, 2 * n))
    idx = idx % n
    theta = 4.0 * np.arcsin(np.clip(d / 2.0, 0.0, 1.0))  # chord |q - q'| = 2 sin(theta / 4)
    rows = np.repeat(np.arange(n), idx.shape[1])
    vals = np.exp(-0.5 * (theta / max(sigma, 1e-9)) ** 2).ravel()
    # Both signs of an entry may appear among the 2k queried: keep each entry's best (first).
    key = rows * n + idx.ravel()
    _, first = np.unique(key, return_index=True)
    order = np.sort(first)
    rows, cols, vals = rows[order], idx.ravel()[order], vals[order]
    # Keep the k nearest per row (the query returns them sorted by distance).
    rank = np.arange(rows.shape[0]) - np.searchsorted(rows, rows)
    keep = rank < k
    D = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n, n))
    s = np.asarray(D.sum(axis=1)).ravel()
    return sp.csr_matrix(sp.diags(1.0 / s) @ D)
