"""OracleLikelihood: scores from the distance to a known ground-truth pose, to test the filters
without networks.

s(R, t) = exp(-|t - t_gt|^2 / (2 sigma_t^2) - theta(R, R_gt)^2 / (2 sigma_r^2)) in [0, 1].
Visible object: w = max(s, w_floor) (flat far from the truth, like a real likelihood: no
gradient leads a lost filter back), L = l_floor + (1 - l_floor) s (like a cosine similarity,
rarely 0 even for a wrong pose) and C = 1 - s_c, where s_c is s with widths ``c_scale`` times
larger (so C is near 0 around the truth and near 1 far from it). ``occluded = True`` makes L, w
uninformative (constant ``occluded_L``) while C stays informative, which is the situation
the Counter-Hypothetical likelihood is for.
"""

from __future__ import annotations

import numpy as np

from chpf.geometry import (
    RotationGrid,
    egocentric_to_allocentric,
    geodesic_angle,
    matrix_to_quat,
    perturb_rotations,
)
from chpf.tracking.types import CodebookScores, Frame, Scores


class OracleLikelihood:
    """Likelihood, single-frame estimator and codebook likelihood backed by a known pose.

    Set the truth per frame with ``set_pose(R, t)`` (R (3,3), t (3,) metres). ``grid``: a
    RotationGrid for the Rao-Blackwellised filters (codebook_scores). ``estimate_noise``:
    (metres, radians) std of the single-frame estimate's error; ``rng`` drives that noise.
    """

    def __init__(
        self,
        sigma_t: float = 0.02,
        sigma_r: float = 0.3,
        c_scale: float = 3.0,
        l_floor: float = 0.2,
        w_floor: float = 1e-4,
        occluded_L: float = 0.5,
        grid: RotationGrid | None = None,
        estimate_noise: tuple[float, float] = (0.005, 0.05),
        rng: np.random.Generator | None = None,
    ) -> None:
        self.sigma_t = float(sigma_t)
        self.sigma_r = float(sigma_r)
        self.c_scale = float(c_scale)
        self.l_floor = float(l_floor)
        self.w_floor = float(w_floor)
        self.occluded_L = float(occluded_L)
        self.occluded = False
        self.grid = grid
        self.estimate_noise = estimate_noise
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.R_gt = np.eye(3)
        self.t_gt = np.array([0.0, 0.0, 1.0])
        self.calls = 0

    def set_pose(self, R: np.ndarray, t: np.ndarray) -> None:
        """Set the ground-truth pose of the current frame."""
        self.R_gt = np.asarray(R, dtype=np.float64)
        self.t_gt = np.asarray(t, dtype=np.float64)

    def _log_s(self, d_t: np.ndarray, d_r: np.ndarray, scale: float) -> np.ndarray:
        return -0.5 * ((d_t / (self.sigma_t * scale)) ** 2 + (d_r / (self.sigma_r * scale)) ** 2)

    def score(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> Scores:
        """Scores of poses R (N,3,3), t (N,3) against the current ground truth."""
        self.calls += 1
        d_t = np.linalg.norm(np.asarray(t) - self.t_gt, axis=-1)
        d_r = geodesic_angle(R, self.R_gt)
        s = np.exp(self._log_s(d_t, d_r, 1.0))
        c = 1.0 - np.exp(self._log_s(d_t, d_r, self.c_scale))
        if self.occluded:
            L = np.full_like(s, self.occluded_L)
            return Scores(L=L, w=L.copy(), C=c, stage_ms={"oracle": 0.0})
        L = self.l_floor + (1.0 - self.l_floor) * s
        return Scores(L=L, w=np.maximum(s, self.w_floor), C=c, stage_ms={"oracle": 0.0})

    def single_frame_estimate(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None:
        """The ground truth plus Gaussian noise (``estimate_noise``)."""
        sig_t, sig_r = self.estimate_noise
        R = perturb_rotations(self.R_gt[None], sig_r, self.rng)[0]
        t = self.t_gt + self.rng.standard_normal(3) * sig_t
        return R, t

    def codebook_scores(self, frame: Frame, t: np.ndarray) -> CodebookScores:
        """cos (N,K) = s_t(t_i) * s_r(grid_k vs the truth's allocentric rotation at t_i)."""
        if self.grid is None:
            raise ValueError("OracleLikelihood.codebook_scores needs a grid")
        self.calls += 1
        t = np.asarray(t, dtype=np.float64)
        d_t = np.linalg.norm(t - self.t_gt, axis=-1)  # (N,)
        R_allo = egocentric_to_allocentric(np.broadcast_to(self.R_gt, (t.shape[0], 3, 3)), t)
        dots = np.abs(matrix_to_quat(R_allo) @ self.grid.quats.T)  # (N, K)
        d_r = 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))
        cos = np.exp(self._log_s(d_t[:, None], d_r, 1.0))
        if self.occluded:
            cos = np.full_like(cos, self.occluded_L)

        def misaligned(idx: np.ndarray) -> np.ndarray:  # C of entry idx_i at t_i, as in score
            d_ri = d_r[np.arange(t.shape[0]), np.asarray(idx)]
            return 1.0 - np.exp(self._log_s(d_t, d_ri, self.c_scale))

        return CodebookScores(cos=cos, stage_ms={"oracle": 0.0}, misaligned=misaligned)

    def depth_weight(self, frame: Frame, idx: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """No depth model in the oracle."""
        return None
