"""The object's shape as the bundle knows it, for drawing: points on its convex hull.

A bundle holds no mesh, but each codebook entry k has a depth crop of the object rendered at
orientation R_k and translation (0, 0, D_r) with intrinsics ``Bundle.depth_K``. Back-projecting
the valid pixels of a few hundred entries spread over the codebook and moving them into the
object's frame (p = R_k^T (X - (0, 0, D_r))) gives a point cloud of its surface; the vertices of
its 3D convex hull project to the silhouette's convex hull under any pose.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from chpf.bundle import Bundle


def surface_points(bundle: Bundle, views: int = 300) -> np.ndarray:
    """(M,3) metres, object frame: the back-projected depth crops of ``views`` codebook entries
    spread over the codebook (module docstring)."""
    idx = np.unique(np.linspace(0, bundle.codebook_size - 1, views).round().astype(np.int64))
    depth = bundle.codebook_depth(idx)
    sd = bundle.depth_size
    v, u = np.mgrid[0:sd, 0:sd]
    pixels = np.stack([u, v, np.ones_like(u)], axis=-1).astype(np.float64)
    rays = pixels @ np.linalg.inv(bundle.depth_K).T  # (Sd,Sd,3), z = 1
    pts = []
    for k, d in zip(idx, depth, strict=True):
        valid = d > 0
        cam = rays[valid] * d[valid, None].astype(np.float64) - bundle.spec.translation
        pts.append(cam @ bundle.grid.rotations[k])  # rows of R_k^T (X - t_r)
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def outline_points(bundle: Bundle, views: int = 300) -> np.ndarray:
    """(M,3) metres, object frame: the vertices of the convex hull of ``surface_points``."""
    pts = surface_points(bundle, views)
    if len(pts) < 4:
        return pts
    return pts[ConvexHull(pts).vertices]


def project_outline(
    points: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, z_min: float
) -> np.ndarray:
    """Pixels (N,M,2) (u, v) of points (M,3) metres, object frame, seen at poses R (N,3,3),
    t (N,3) metres with intrinsics K (3,3); depths clamped to at least z_min metres."""
    cam = np.matmul(R, points.T) + t[:, :, None]  # (N,3,M)
    z = np.maximum(cam[:, 2], z_min)
    return np.stack([K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]], -1)
