"""Rotations, rotation grids and camera geometry, batched with numpy (batch axis first).

Conventions: rotations are (..., 3, 3) matrices; quaternions are (w, x, y, z), normalised,
with w >= 0; axis-angle vectors have norm = angle in radians; poses map object to camera;
the camera is OpenCV's (x right, y down, z forward).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from chpf.errors import ImageSizeError

__all__ = [
    "IMAGE_SIZE_TOL",
    "RotationGrid",
    "allocentric_to_egocentric",
    "average_quaternions",
    "axis_angle_to_matrix",
    "check_image_size",
    "egocentric_to_allocentric",
    "geodesic_angle",
    "matrix_to_axis_angle",
    "matrix_to_quat",
    "perturb_rotations",
    "project_points",
    "quat_to_matrix",
    "random_rotations",
    "ray_rotation",
    "so3_grid",
]

# Root of x^4 = x + 4 (Alexa, "Super-Fibonacci Spirals", CVPR 2022).
_SF_PSI = 1.533751168755204288118041
_SF_PHI = np.sqrt(2.0)
# Rotations converted and looked up at once by RotationGrid.nearest (bounds temporary memory).
_NEAREST_CHUNK_ROWS = 1 << 16


def _canonical(q: np.ndarray) -> np.ndarray:
    """Normalise quaternions (..., 4) and flip their sign so that w >= 0."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) (w, x, y, z; normalised here) -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    ]  # fmt: skip
    return np.stack(rows, axis=-1).reshape((*q.shape[:-1], 3, 3))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> quaternions (..., 4), normalised, w >= 0.

    Shepperd's method: of the four algebraically equivalent formulas, each element uses the one
    with the largest pivot, so the result is accurate for every rotation (also near 180 deg).
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # Candidate k (row k, symmetric) has 4*q_k^2 as its pivot (q_0 = w); each row is
    # proportional to q.
    cands = np.empty((*R.shape[:-2], 4, 4))
    cands[..., 0, 0] = 1.0 + m00 + m11 + m22
    cands[..., 1, 1] = 1.0 + m00 - m11 - m22
    cands[..., 2, 2] = 1.0 - m00 + m11 - m22
    cands[..., 3, 3] = 1.0 - m00 - m11 + m22
    cands[..., 0, 1] = cands[..., 1, 0] = m21 - m12
    cands[..., 0, 2] = cands[..., 2, 0] = m02 - m20
    cands[..., 0, 3] = cands[..., 3, 0] = m10 - m01
    cands[..., 1, 2] = cands[..., 2, 1] = m01 + m10
    cands[..., 1, 3] = cands[..., 3, 1] = m02 + m20
    cands[..., 2, 3] = cands[..., 3, 2] = m12 + m21
    best = np.argmax(np.diagonal(cands, axis1=-2, axis2=-1), axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    return _canonical(q)


def _skew(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) -> cross-product matrices (..., 3, 3)."""
    x, y, z = np.moveaxis(v, -1, 0)
    o = np.zeros_like(x)
    return np.stack([o, -z, y, z, o, -x, -y, x, o], axis=-1).reshape((*v.shape[:-1], 3, 3))


def axis_angle_to_matrix(v: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3) (|v| = angle, rad) -> rotation matrices (..., 3, 3).

    Rodrigues' formula R = I + a [v]x + b [v]x^2 with a = sin(t)/t, b = (1 - cos t)/t^2,
    using Taylor series for small angles.
    """
    v = np.asarray(v, dtype=np.float64)
    t2 = np.sum(v * v, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    K = _skew(v)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angle vectors (..., 3), angle in [0, pi]."""
    q = matrix_to_quat(R)
    w = q[..., 0]
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-8
    # angle / s -> 2 / w for s -> 0 (w ~ 1 there because w >= 0).
    scale = np.where(small, 2.0 / np.maximum(w, 1e-12), angle / np.where(small, 1.0, s))
    return xyz * scale[..., None]


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """n rotations (n, 3, 3) drawn uniformly (Haar measure) from SO(3)."""
    q = rng.standard_normal((int(n), 4))
    return quat_to_matrix(q)


def so3_grid(k: int) -> np.ndarray:
    """Deterministic near-uniform grid of k rotations (k, 3, 3): a super-Fibonacci spiral.

    Points q_i on S^3 (Alexa, CVPR 2022), i = 0..k-1, s = i + 1/2:
    q_i = (sqrt(s/k) sin(2 pi s / phi), sqrt(s/k) cos(2 pi s / phi),
           sqrt(1 - s/k) sin(2 pi s / psi), sqrt(1 - s/k) cos(2 pi s / psi)),
    phi = sqrt(2), psi^4 = psi + 4. Any k >= 1 works; the covering radius shrinks like k^(-1/3).
    """
    k = int(k)
    if k < 1:
        raise ValueError(f"so3_grid: k must be >= 1, got {k}")
    s = np.arange(k, dtype=np.float64) + 0.5
    r = np.sqrt(s / k)
    r_c = np.sqrt(1.0 - s / k)
    alpha = 2.0 * np.pi * s / _SF_PHI
    beta = 2.0 * np.pi * s / _SF_PSI
    q = np.stack([r * np.sin(alpha), r * np.cos(alpha), r_c * np.sin(beta), r_c * np.cos(beta)], -1)
    return quat_to_matrix(q)


class RotationGrid:
    """A fixed set of K rotations with nearest-entry lookup (argmax_k |q . q_k|).

    For unit quaternions |q - p|^2 = 2 - 2 q.p, so the entry with the largest |q . q_k| is the
    Euclidean nearest neighbour of q among {q_k} and {-q_k}: a KD-tree over these 2K points in
    R^4 (built on the first lookup) answers it exactly in O(log K) per query, without the
    (N, K) score matrix.
    """

    def __init__(self, rotations: np.ndarray) -> None:
        """rotations: (K, 3, 3), K >= 1."""
        rotations = np.asarray(rotations, dtype=np.float64)
        if rotations.ndim != 3 or rotations.shape[1:] != (3, 3) or rotations.shape[0] < 1:
            raise ValueError(f"RotationGrid: expected (K, 3, 3) rotations, got {rotations.shape}")
        self.rotations: np.ndarray = rotations
        self.quats: np.ndarray = matrix_to_quat(rotations)
        self._tree: cKDTree | None = None

    def __len__(self) -> int:
        return int(self.rotations.shape[0])

    @classmethod
    def uniform(cls, k: int) -> RotationGrid:
        """Grid of so3_grid(k)."""
        return cls(so3_grid(k))

    def nearest(self, R: np.ndarray) -> np.ndarray:
        """Index (N,) int64 of the nearest grid entry (smallest geodesic angle) of each R (N,3,3).

        Any leading shape (..., 3, 3) works and is kept. Queries run in chunks of rows, so
        temporary memory stays bounded for large N.
        """
        if self._tree is None:
            self._tree = cKDTree(np.concatenate([self.quats, -self.quats]))
        R = np.asarray(R, dtype=np.float64)
        lead = R.shape[:-2]
        R = R.reshape(-1, 3, 3)
        out = np.empty(R.shape[0], dtype=np.int64)
        k = len(self)
        for start in range(0, R.shape[0], _NEAREST_CHUNK_ROWS):
            q = matrix_to_quat(R[start : start + _NEAREST_CHUNK_ROWS])
            _, idx = self._tree.query(q, k=1)
            out[start : start + _NEAREST_CHUNK_ROWS] = idx % k
        return out.reshape(lead)


def perturb_rotations(R: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """R' = exp([w]x) @ R with w ~ N(0, sigma^2 I) per rotation; R (N, 3, 3), sigma in rad."""
    R = np.asarray(R, dtype=np.float64)
    w = rng.standard_normal((*R.shape[:-2], 3)) * float(sigma)
    return axis_angle_to_matrix(w) @ R


def geodesic_angle(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of R1^T R2; inputs (..., 3, 3) broadcast against each other."""
    Rr = np.swapaxes(np.asarray(R1, dtype=np.float64), -1, -2) @ np.asarray(R2, dtype=np.float64)
    c = 0.5 * (np.trace(Rr, axis1=-2, axis2=-1) - 1.0)
    v = np.stack(
        [
            Rr[..., 2, 1] - Rr[..., 1, 2],
            Rr[..., 0, 2] - Rr[..., 2, 0],
            Rr[..., 1, 0] - Rr[..., 0, 1],
        ],
        axis=-1,
    )
    s = 0.5 * np.linalg.norm(v, axis=-1)
    return np.arctan2(s, c)


def average_quaternions(q: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Weighted mean rotation (4,) of quaternions q (N, 4): Markley's eigenvector method.

    The result is the eigenvector of sum_i w_i q_i q_i^T with the largest eigenvalue, so the
    sign of each q_i does not matter. Weights (N,) must be >= 0 with a positive sum
    (None = equal weights). Returned normalised with w >= 0.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4 or q.shape[0] < 1:
        raise ValueError(f"average_quaternions: expected (N, 4) quaternions, got {q.shape}")
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    if w is None:
        w = np.full(q.shape[0], 1.0 / q.shape[0])
    else:
        w = np.asarray(w, dtype=np.float64).reshape(-1)
        if w.shape[0] != q.shape[0]:
            raise ValueError(f"average_quaternions: {w.shape[0]} weights for {q.shape[0]} quats")
        total = w.sum()
        if not np.all(np.isfinite(w)) or np.any(w < 0) or total <= 0:
            raise ValueError("average_quaternions: weights must be finite, >= 0, sum > 0")
        w = w / total
    M = np.einsum("n,ni,nj->ij", w, q, q)
    _, vecs = np.linalg.eigh(M)
    return _canonical(vecs[:, -1])


def ray_rotation(t: np.ndarray) -> np.ndarray:
    """Minimal rotation (..., 3, 3) taking the optical axis (0, 0, 1) onto t / |t|; t (..., 3).

    With d = t/|t| = (x, y, z): R = [[1 - x^2/(1+z), -xy/(1+z), x], [-xy/(1+z), 1 - y^2/(1+z), y],
    [-x, -y, z]] (rotation about z x d). Identity for t on the +z axis and for t = 0;
    t on the -z axis (no unique minimal rotation) gives the half-turn about x.
    """
    t = np.asarray(t, dtype=np.float64)
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    if np.all(norm > 0.0):
        d = t / norm
        if np.all(d[..., 2] >= 0.0):  # the usual case: the same numbers, fewer numpy calls
            return _forward_ray_rotation(d)
    zero = norm[..., 0] == 0.0
    d = np.where(norm > 0.0, t / np.where(norm > 0.0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    x, y, z = np.moveaxis(d, -1, 0)
    # inv = 1 / (1 + z) = (1 - z) / (x^2 + y^2); the second form stays accurate for z near -1.
    s2 = x * x + y * y
    opp = (z < 0.0) & (s2 == 0.0)
    inv = np.where(z >= 0.0, 1.0 / (1.0 + np.abs(z)), (1.0 - z) / np.where(s2 > 0.0, s2, 1.0))
    R = np.stack(
        [
            1.0 - x * x * inv, -x * y * inv, x,
            -x * y * inv, 1.0 - y * y * inv, y,
            -x, -y, z,
        ],
        axis=-1,
    ).reshape((*t.shape[:-1], 3, 3))  # fmt: skip
    flip = np.diag([1.0, -1.0, -1.0])
    R = np.where(opp[..., None, None], flip, R)
    return np.where(zero[..., None, None], np.eye(3), R)


def _forward_ray_rotation(d: np.ndarray) -> np.ndarray:
    """``ray_rotation`` of unit directions d (..., 3) with z >= 0: its formula, filled in place
    of the general case's stack and selections (bit for bit the same result)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    inv = 1.0 / (1.0 + z)
    xy = -x * y * inv
    R = np.empty((*d.shape[:-1], 3, 3))
    R[..., 0, 0] = 1.0 - x * x * inv
    R[..., 0, 1] = xy
    R[..., 0, 2] = x
    R[..., 1, 0] = xy
    R[..., 1, 1] = 1.0 - y * y * inv
    R[..., 1, 2] = y
    R[..., 2, 0] = -x
    R[..., 2, 1] = -y
    R[..., 2, 2] = z
    return R


def egocentric_to_allocentric(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Allocentric rotation R_ray(t)^T @ R; R (..., 3, 3), t (..., 3) metres."""
    return np.swapaxes(ray_rotation(t), -1, -2) @ np.asarray(R, dtype=np.float64)


def allocentric_to_egocentric(R_allo: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Egocentric rotation R_ray(t) @ R_allo; R_allo (..., 3, 3), t (..., 3) metres."""
    return ray_rotation(t) @ np.asarray(R_allo, dtype=np.float64)


def project_points(X: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) (u, v) of camera-frame points X (..., 3) (metres), K (3, 3).

    OpenCV convention: u = (K X)_0 / (K X)_2, v = (K X)_1 / (K X)_2; pixel centres at integers.
    Points with z = 0 give inf/nan.
    """
    X = np.asarray(X, dtype=np.float64)
    p = X @ np.asarray(K, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[..., :2] / p[..., 2:3]


IMAGE_SIZE_TOL = 0.2
"""Relative tolerance of ``check_image_size`` (principal points are near the image centre)."""


def check_image_size(width: int, height: int, K: np.ndarray, tol: float = IMAGE_SIZE_TOL) -> None:
    """Raise ImageSizeError if a ``width`` x ``height`` pixel image cannot belong to K (3,3).

    The principal point of a camera lies near the image centre, so the image's size should be
    about (2 cx + 1, 2 cy + 1) pixels; more than ``tol`` (relative) off in either direction means
    the image was resized or cropped without adjusting K (e.g. a 320x240 image with the K of a
    640x480 camera, whose principal point still falls inside the image).
    """
    cx, cy = float(K[0, 2]), float(K[1, 2])
    want_w, want_h = 2.0 * cx + 1.0, 2.0 * cy + 1.0
    off_w = abs(width - want_w) / max(want_w, 1.0)
    off_h = abs(height - want_h) / max(want_h, 1.0)
    if not (off_w <= tol and off_h <= tol):
        raise ImageSizeError(
            f"image is {width}x{height} but the principal point ({cx:g}, {cy:g}) of K implies "
            f"about {want_w:.0f}x{want_h:.0f} (2 cx + 1, 2 cy + 1; more than {tol:.0%} off): "
            "image size and K disagree"
        )
