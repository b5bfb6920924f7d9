"""Candidate orientations from the codebook: phi_cand informed by the detection box's crop.

The crop at the box centre is compared with every codebook entry (one encoder pass per frame,
chpf.tracking.bundle_likelihood.BundleLikelihood.box_centre_cosines). With ``rerank`` M > 0 the
classifier then scores that crop against the M entries of best cosine, and entry k among them is
drawn with probability proportional to exp(-(C_k - min C) / c_temperature); with M = 0 entry k
of the whole codebook is drawn with probability proportional to exp((c_k - max c) /
temperature). Either way it is turned egocentric through each candidate's own ray. A share
``uniform_share`` stays uniform on SO(3), so that orientations the crop's look-up misses
(occlusion, flips) keep being tried. The paper's phi_cand is uniform (``rotations: uniform``);
this is the option ``codebook`` (the default).

Why the classifier: a detection box is a few pixels off the object's centre, and the crop cut
there is misplaced. The autoencoder's embedding follows a misplaced crop (it is trained to, so
that L tells a misplaced particle apart), and the cosine then ranks the right orientation
anywhere in the codebook. The classifier, trained on jittered crops, still tells it: on a
textured duck the first entry within 20 deg of the truth ranked 3rd to 3603rd by cosine at
boxes 5-21 px off (of a 74-107 px side), while the classifier gave the truth's entry C
0.01-0.22 there (docs/chpf-ablations.md).
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

    def box_centre_misalignment(
        self, frame: Frame, t0: np.ndarray, idx: np.ndarray
    ) -> np.ndarray: ...


@dataclass
class CodebookRotations:
    """RotationSource drawing codebook orientations that match the box's crop (module doc)."""

    scorer: BoxCentreScorer
    temperature: float = 0.05
    uniform_share: float = 0.25
    rerank: int = 1024
    c_temperature: float = 0.05

    def __post_init__(self) -> None:
        if self.temperature <= 0 or self.c_temperature <= 0:
            raise ConfigError(
                f"candidate temperatures must be > 0, got {self.temperature}, {self.c_temperature}"
            )
        if self.rerank < 0:
            raise ConfigError(f"candidate rerank must be >= 0, got {self.rerank}")
        if not 0.0 <= self.uniform_share <= 1.0:
            raise ConfigError(
                f"candidate uniform share must be in [0, 1], got {self.uniform_share}"
            )

    def probabilities(self, cos: np.ndarray) -> np.ndarray:
        """Sampling probabilities (K,) of the codebook entries for cosines cos (K,), without
        the classifier (``rerank`` 0)."""
        return _softmax(np.asarray(cos, dtype=np.float64) / self.temperature)

    def entries(
        self, frame: Frame, cos: np.ndarray, t0: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The entries (M,) that candidates are drawn from and their probabilities (M,), for
        the box crop's cosines cos (K,) at the crop's translation t0 (3,) (module docstring)."""
        if self.rerank <= 0:
            return np.arange(cos.shape[0]), self.probabilities(cos)
        m = min(self.rerank, cos.shape[0])
        top = np.argpartition(-cos, m - 1)[:m]
        C = np.asarray(self.scorer.box_centre_misalignment(frame, t0, top), dtype=np.float64)
        return top, _softmax(-C / self.c_temperature)

    def sample(self, n: int, frame: Frame, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """n egocentric orientations (n,3,3) for candidate translations t (n,3) metres."""
        R = random_rotations(n, rng)
        n_cb = n - round(self.uniform_share * n)
        found = self.scorer.box_centre_cosines(frame) if n_cb > 0 else None
        if found is None:
            return R
        idx, p = self.entries(frame, *found)
        k = idx[rng.choice(idx.shape[0], n_cb, p=p)]
        R[:n_cb] = allocentric_to_egocentric(self.scorer.grid.rotations[k], t[:n_cb])
        return R


def _softmax(logits: np.ndarray) -> np.ndarray:
    """exp(logits - max) normalised to sum 1 (same shape)."""
    p = np.exp(logits - np.max(logits))
    return p / p.sum()
