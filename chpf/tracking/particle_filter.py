"""The 6D particle-filter core shared by CH-PF, SRL, Aug. MCL, Annealing, MCL + E2E, fixed-rate
and no reinvigoration; only the Strategy differs. The frame loop is ``FilterLoop``'s.

Per frame with a detection box: predict (random walk), weigh (one likelihood call per annealing
layer, one for every other strategy), estimate (weighted mean translation and quaternion
average), resample (N - round(alpha N) particles from the belief, round(alpha N) from the
strategy's proposal or phi_cand).
"""

from __future__ import annotations

import time

import numpy as np

from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.estimate import weighted_pose
from chpf.tracking.filter_loop import FilterLoop, Particles, Weighed
from chpf.tracking.motion import RandomWalk
from chpf.tracking.resampling import Weights
from chpf.tracking.strategies import Strategy
from chpf.tracking.timing import add_ms, ms_since
from chpf.tracking.types import Frame, Likelihood


class ParticleFilter(FilterLoop):
    """Particle filter over 6D pose (R (N,3,3), t (N,3) metres) with a reinvigoration strategy.

    Use ``step(frame) -> TrackResult`` per frame and ``reset()`` between sequences. The state
    is public (``R``, ``t``, ``weights``) so that tests and tools can inspect or set it.
    resampling: a scheme of ``chpf.tracking.resampling.RESAMPLERS``.
    """

    def __init__(
        self,
        likelihood: Likelihood,
        strategy: Strategy,
        n_particles: int = 50,
        motion: RandomWalk | None = None,
        candidates: CandidateSampler | None = None,
        rng: np.random.Generator | None = None,
        resampling: str = "systematic",
    ) -> None:
        super().__init__(n_particles, rng, f"{type(self).__name__}[{strategy.name}]", resampling)
        self.likelihood = likelihood
        self.strategy = strategy
        self.motion = motion or RandomWalk()
        self.candidates = candidates or CandidateSampler()
        self.reset()

    @property
    def keep_belief(self) -> bool:
        """The strategy's choice (``Strategy.keeps_belief``)."""
        return self.strategy.keeps_belief

    def reset(self) -> None:
        """Forget the particles and the estimate (start of a new sequence)."""
        super().reset()
        self.R: np.ndarray | None = None
        self.t: np.ndarray | None = None
        self.strategy.reset()

    @property
    def initialised(self) -> bool:
        return self.R is not None

    def set_particles(self, R: np.ndarray, t: np.ndarray) -> None:
        """Replace the particle set (uniform weights), e.g. to force a state in tests."""
        self.R = np.array(R, dtype=np.float64).reshape(self.n, 3, 3)
        self.t = np.array(t, dtype=np.float64).reshape(self.n, 3)
        self.weights = np.full(self.n, 1.0 / self.n)
        self.fresh = np.zeros(self.n, dtype=bool)

    # ------------------------------------------------------------------ FilterLoop hooks
    def _initialise(self, frame: Frame) -> None:
        self.set_particles(*self.candidates.sample(self.n, frame, self.rng))
        self.fresh = np.ones(self.n, dtype=bool)

    def _predict(self) -> None:
        assert self.R is not None and self.t is not None
        self.R, self.t = self.motion.predict(self.R, self.t, self.rng)

    def _weigh(self, frame: Frame, stage_ms: dict[str, float]) -> Weighed:
        """Score the particles; with annealing layers, resample and diffuse between layers
        (layer m resamples from the weights tempered by betas[m])."""
        assert self.R is not None and self.t is not None
        betas = self.strategy.betas
        for m, beta in enumerate(betas):
            t0 = time.perf_counter()
            scores = self.likelihood.score(frame, self.R, self.t)
            if scores.R is not None:  # the likelihood's orientation search moved them
                self.R = scores.R
            stage_ms["likelihood"] = stage_ms.get("likelihood", 0.0) + ms_since(t0)
            add_ms(stage_ms, scores.stage_ms)
            weights = Weights.from_weights(self.strategy.importance(scores))
            if m == len(betas) - 1:
                a = self.strategy.alpha(scores, weights.W, self.fresh)
                alpha = float(np.clip(a, 0.0, 1.0))
                sum_c = float("nan") if scores.C is None else float(np.nansum(scores.C))
                return Weighed(weights, alpha, float(np.nansum(scores.L)), sum_c)
            t0 = time.perf_counter()
            layer = weights.tempered(beta)
            if layer.W is not None:
                idx = self.resample_indices(layer.W, self.n, self.rng)
                self.R, self.t = self.R[idx], self.t[idx]
            scale = self.strategy.layer_decay ** (m + 1)
            self.R, self.t = self.motion.predict(self.R, self.t, self.rng, scale)
            stage_ms["anneal"] = stage_ms.get("anneal", 0.0) + ms_since(t0)
        raise AssertionError("unreachable")  # betas is never empty

    def _estimate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        assert self.R is not None and self.t is not None
        return weighted_pose(self.R, self.t, w)

    def _take(self, idx: np.ndarray) -> Particles:
        assert self.R is not None and self.t is not None
        return self.R[idx], self.t[idx]

    def _draw(self, frame: Frame, n: int) -> Particles:
        """The strategy's proposal, or phi_cand when it has none."""
        prop = self.strategy.propose(frame, n, self.rng, self.likelihood)
        if prop is not None:
            return prop
        return self.candidates.sample(n, frame, self.rng, self.estimate)

    def _assign(self, particles: Particles) -> None:
        self.R, self.t = particles
