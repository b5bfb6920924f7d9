"""Candidate orientations from the codebook: phi_cand informed by the detection box's crop.

The crop at the box centre is compared with every codebook entry (one encoder pass per frame,
chpf.tracking.bundle_likelihood.BundleLikelihood.box_centre_cosines); entry k is drawn with
probability proportional to exp((c_k - max c) / temperature) and turned egocentric through each
candidate's own ray. A share ``uniform_share`` stays uniform on SO(3), so that orientations the
crop's look-up misses (occlusion, flips) keep being tried. The paper's phi_cand is uniform
(``candidate_rotations: uniform``, the default); this is the option ``codebook``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from chpf.errors import ConfigError
from chpf.geometry import RotationGrid, allocentric_to_egocentric, random_rotations
from chpf.tracking.types import Frame


class BoxCentreScorer(Protocol):
    """What CodebookRotations needs from a likelihood (BundleLikelihood has both)."""

    grid: RotationGrid

    def box_centre_cosines(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None: ...


@dataclass
class CodebookRotations:
    """RotationSource drawing codebook orientations that match the box's crop (module doc)."""

    scorer: BoxCentreScorer
    temperature: float = 0.05
    uniform_share: float = 0.25

    def __post_init__(self) -> None:
        if self.temperature <= 0:
            raise ConfigError(f"candidate temperature must be > 0, got {self.temperature}")
        if not 0.0 <= self.uniform_share <= 1.0:
            raise ConfigError(
                f"candidate uniform share must be in [0, 1], got {self.uniform_share}"
            )

    def probabilities(self, cos: np.ndarray) -> np.ndarray:
        """Sampling probabilities (K,) of the codebook entries for cosines cos (K,)."""
        logits = (np.asarray(cos, dtype=np.float64) - np.max(cos)) / self.temperature
        p = np.exp(logits)
        return p / p.sum()

    def sample(self, n: int, frame: Frame, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """n egocentric orientations (n,3,3) for candidate translations t (n,3) metres."""
        R = random_rotations(n, rng)
        n_cb = n - round(self.uniform_share * n)
        found = self.scorer.box_centre_cosines(frame) if n_cb > 0 else None
        if found is None:
            return R
        k = rng.choice(found[0].shape[0], n_cb, p=self.probabilities(found[0]))
        R[:n_cb] = allocentric_to_egocentric(self.scorer.grid.rotations[k], t[:n_cb])
        return R
