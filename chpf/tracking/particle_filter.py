"""The 6D particle-filter core shared by CH-PF, SRL, Aug. MCL, Annealing, MCL + E2E, fixed-rate
and no reinvigoration; only the Strategy differs.

Per frame with a detection box: predict (random walk), weigh (one likelihood call per annealing
layer, one for every other strategy), estimate (weighted mean translation and quaternion
average), resample (systematic resampling for N - round(alpha N) particles from the belief,
round(alpha N) from the strategy's proposal or phi_cand). The first frame with a box draws all
N particles from phi_cand. A frame without a box is predict-only and keeps the last estimate.
When every weight is zero or NaN the frame's alpha is 1 (full reinvigoration) and a
WeightCollapseWarning is given once per filter.
"""

from __future__ import annotations

import time

import numpy as np

from chpf.tracking.candidates import CandidateSampler, valid_box
from chpf.tracking.estimate import weighted_pose
from chpf.tracking.motion import RandomWalk
from chpf.tracking.resampling import effective_sample_size, normalise_weights, systematic_resample
from chpf.tracking.strategies import Strategy
from chpf.tracking.timing import add_ms, ms_since
from chpf.tracking.types import Frame, Likelihood, Scores, TrackResult
from chpf.tracking.warn import CollapseWarner

_NAN = float("nan")


class ParticleFilter:
    """Particle filter over 6D pose (R (N,3,3), t (N,3) metres) with a reinvigoration strategy.

    Use ``step(frame) -> TrackResult`` per frame and ``reset()`` between sequences. The state
    is public (``R``, ``t``, ``weights``) so that tests and tools can inspect or set it.
    """

    def __init__(
        self,
        likelihood: Likelihood,
        strategy: Strategy,
        n_particles: int = 50,
        motion: RandomWalk | None = None,
        candidates: CandidateSampler | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        if n_particles < 1:
            raise ValueError(f"n_particles must be >= 1, got {n_particles}")
        self.likelihood = likelihood
        self.strategy = strategy
        self.n = int(n_particles)
        self.motion = motion or RandomWalk()
        self.candidates = candidates or CandidateSampler()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.warner = CollapseWarner(f"{type(self).__name__}[{strategy.name}]")
        self.reset()

    def reset(self) -> None:
        """Forget the particles and the estimate (start of a new sequence)."""
        self.R: np.ndarray | None = None
        self.t: np.ndarray | None = None
        self.weights: np.ndarray = np.full(self.n, 1.0 / self.n)
        self.estimate: tuple[np.ndarray, np.ndarray] | None = None
        self.strategy.reset()

    @property
    def initialised(self) -> bool:
        return self.R is not None

    def set_particles(self, R: np.ndarray, t: np.ndarray) -> None:
        """Replace the particle set (uniform weights), e.g. to force a state in tests."""
        self.R = np.array(R, dtype=np.float64).reshape(self.n, 3, 3)
        self.t = np.array(t, dtype=np.float64).reshape(self.n, 3)
        self.weights = np.full(self.n, 1.0 / self.n)

    # ------------------------------------------------------------------ one frame
    def _result(
        self, alpha: float, scores: Scores | None, ess: float, stage_ms: dict[str, float]
    ) -> TrackResult:
        est = self.estimate
        sum_l = _NAN if scores is None else float(np.nansum(scores.L))
        sum_c = _NAN if scores is None or scores.C is None else float(np.nansum(scores.C))
        return TrackResult(
            R=None if est is None else est[0].copy(),
            t=None if est is None else est[1].copy(),
            alpha=float(alpha),
            sum_L=sum_l,
            sum_C=sum_c,
            ess=float(ess),
            stage_ms=stage_ms,
            ok=est is not None,
            weighed=scores is not None,
        )

    def _weigh(self, frame: Frame, stage_ms: dict[str, float]) -> Scores:
        """Score the particles; with annealing layers, resample and diffuse between layers."""
        assert self.R is not None and self.t is not None
        betas = self.strategy.betas
        for m, beta in enumerate(betas):
            t0 = time.perf_counter()
            scores = self.likelihood.score(frame, self.R, self.t)
            stage_ms["likelihood"] = stage_ms.get("likelihood", 0.0) + ms_since(t0)
            add_ms(stage_ms, scores.stage_ms)
            if m == len(betas) - 1:
                return scores
            t0 = time.perf_counter()
            w = normalise_weights(np.power(np.clip(scores.w, 0.0, None), beta))
            if w is not None:
                idx = systematic_resample(w, self.n, self.rng)
                self.R, self.t = self.R[idx], self.t[idx]
            scale = self.strategy.layer_decay ** (m + 1)
            self.R, self.t = self.motion.predict(self.R, self.t, self.rng, scale)
            stage_ms["anneal"] = stage_ms.get("anneal", 0.0) + ms_since(t0)
        raise AssertionError("unreachable")  # betas is never empty

    def step(self, frame: Frame) -> TrackResult:
        """Process one frame; returns the estimate and diagnostics (see TrackResult)."""
        t_start = time.perf_counter()
        stage_ms: dict[str, float] = {}
        box = valid_box(frame.box)
        t0 = time.perf_counter()
        if self.R is None or self.t is None:
            if box is None:
                return self._result(_NAN, None, _NAN, {"total": ms_since(t_start)})
            self.set_particles(*self.candidates.sample(self.n, frame, self.rng))
            stage_ms["init"] = ms_since(t0)
        else:
            self.R, self.t = self.motion.predict(self.R, self.t, self.rng)
            stage_ms["predict"] = ms_since(t0)
            if box is None:
                stage_ms["total"] = ms_since(t_start)
                return self._result(_NAN, None, _NAN, stage_ms)

        scores = self._weigh(frame, stage_ms)

        t0 = time.perf_counter()
        alpha = float(np.clip(self.strategy.alpha(scores), 0.0, 1.0))
        w = normalise_weights(scores.w)
        if w is None:
            self.warner.collapse()
            alpha, ess = 1.0, 0.0
            if self.estimate is None:  # nothing better: the mean of the (uninformed) particles
                self.estimate = weighted_pose(self.R, self.t, np.full(self.n, 1.0 / self.n))
        else:
            self.weights = w
            ess = effective_sample_size(w)
            self.estimate = weighted_pose(self.R, self.t, w)
        stage_ms["estimate"] = ms_since(t0)

        t0 = time.perf_counter()
        self._resample(frame, w, alpha)
        stage_ms["resample"] = ms_since(t0)
        stage_ms["total"] = ms_since(t_start)
        return self._result(alpha, scores, ess, stage_ms)

    def _resample(self, frame: Frame, w: np.ndarray | None, alpha: float) -> None:
        """New particle set: N - round(alpha N) from the belief, the rest reinvigorated."""
        assert self.R is not None and self.t is not None
        n_cand = self.n if w is None else round(alpha * self.n)
        n_bel = self.n - n_cand
        parts_R, parts_t = [], []
        if n_bel > 0:
            idx = systematic_resample(w, n_bel, self.rng)
            parts_R.append(self.R[idx])
            parts_t.append(self.t[idx])
        if n_cand > 0:
            prop = self.strategy.propose(frame, n_cand, self.rng, self.likelihood)
            if prop is None:
                prop = self.candidates.sample(n_cand, frame, self.rng)
            parts_R.append(prop[0])
            parts_t.append(prop[1])
        self.R = np.concatenate(parts_R)
        self.t = np.concatenate(parts_t)
        self.weights = np.full(self.n, 1.0 / self.n)
