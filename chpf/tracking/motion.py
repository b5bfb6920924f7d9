"""Motion model: a random walk in translation (metres) and rotation (axis-angle, radians)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chpf.geometry import perturb_rotations


@dataclass
class RandomWalk:
    """Random-walk motion model.

    sigma_t: standard deviation of the translation step, metres (a float for x, y, z alike, or
    3 values). sigma_r: standard deviation of each axis-angle component of the rotation step,
    radians (R' = exp([w]x) R, w ~ N(0, sigma_r^2 I)).
    """

    sigma_t: float | tuple[float, float, float] = 0.01
    sigma_r: float = 0.05

    def predict(
        self, R: np.ndarray, t: np.ndarray, rng: np.random.Generator, scale: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Diffuse poses R (N,3,3), t (N,3); ``scale`` multiplies both sigmas. New arrays."""
        t_new = self.predict_translation(t, rng, scale)
        R_new = perturb_rotations(R, self.sigma_r * scale, rng) if self.sigma_r > 0 else R.copy()
        return R_new, t_new

    def predict_translation(
        self, t: np.ndarray, rng: np.random.Generator, scale: float = 1.0
    ) -> np.ndarray:
        """Diffuse translations t (N,3) only (Rao-Blackwellised filters)."""
        sig_t = np.broadcast_to(np.asarray(self.sigma_t, dtype=np.float64), (3,)) * scale
        return t + rng.standard_normal(t.shape) * sig_t
