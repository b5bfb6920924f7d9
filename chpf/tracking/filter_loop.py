"""The per-frame loop that every particle filter runs (the 6D filter and PoseRBPF).

A filter with a box: the first frame initialises the particles from phi_cand, later frames
predict; then weigh, estimate and resample N - round(alpha N) particles from the belief and
round(alpha N) from the reinvigoration proposal (with ``keep_belief``: N from the belief, so
that N + round(alpha N) particles are weighed at the next frame and the drawn ones join the
belief instead of replacing part of it). A frame without a box or a search region
(``Frame.region``, phi_cand's stand-in for a box) is predict-only and keeps the last
estimate. A collapse (all log-weights -inf) sets alpha to 1, warns once per filter and keeps
the last estimate (the uniform-weight estimate when there is none yet).
A subclass supplies the hooks ``_initialise``, ``_predict``, ``_weigh``, ``_estimate``,
``_take``, ``_draw`` and ``_assign`` on its own particle representation.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from chpf.tracking.candidates import valid_box
from chpf.tracking.resampling import Weights, resampler
from chpf.tracking.timing import ms_since
from chpf.tracking.types import Frame, TrackResult
from chpf.tracking.warn import CollapseWarner

_NAN = float("nan")
Particles = tuple[np.ndarray, ...]  # the arrays of one particle set, first axis the particle


class Weighed(NamedTuple):
    """One weighing: the weights, the frame's reinvigoration rate (used unless the weights
    collapse) and the recorded sums of L and C (nan when not given)."""

    weights: Weights
    alpha: float
    sum_L: float
    sum_C: float = _NAN


class FilterLoop:
    """Base of the particle filters: ``step(frame) -> TrackResult``, ``reset()``; the state
    ``weights`` (N,; N + round(alpha N) after a resampling with ``keep_belief``) and
    ``estimate`` (R (3,3), t (3,)) or None."""

    keep_belief: bool = False  # the drawn particles join N from the belief (module docstring)

    def __init__(
        self, n_particles: int, rng: np.random.Generator | None, name: str, resampling: str
    ) -> None:
        if n_particles < 1:
            raise ValueError(f"n_particles must be >= 1, got {n_particles}")
        self.n = int(n_particles)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.resample_indices = resampler(resampling)
        self.warner = CollapseWarner(name)

    def reset(self) -> None:
        """Forget the particles and the estimate (start of a new sequence)."""
        self.weights: np.ndarray = np.full(self.n, 1.0 / self.n)
        self.fresh: np.ndarray = np.ones(self.n, dtype=bool)  # drawn by _draw at the last resample
        self.estimate: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ hooks
    @property
    def initialised(self) -> bool:
        raise NotImplementedError

    def _initialise(self, frame: Frame) -> None:
        """Draw all N particles from phi_cand."""
        raise NotImplementedError

    def _predict(self) -> None:
        """Apply the motion model to the particles."""
        raise NotImplementedError

    def _weigh(self, frame: Frame, stage_ms: dict[str, float]) -> Weighed:
        """Score the particles (adds its stage times to stage_ms)."""
        raise NotImplementedError

    def _estimate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose estimate (R (3,3), t (3,)) of the particles under normalised weights w (N,)."""
        raise NotImplementedError

    def _take(self, idx: np.ndarray) -> Particles:
        """The particles at indices idx (n,) (the belief's share of the new set)."""
        raise NotImplementedError

    def _draw(self, frame: Frame, n: int) -> Particles:
        """n reinvigorated particles."""
        raise NotImplementedError

    def _assign(self, particles: Particles) -> None:
        """Make particles (N of them) the filter's particle set."""
        raise NotImplementedError

    # ------------------------------------------------------------------ one frame
    def step(self, frame: Frame) -> TrackResult:
        """Process one frame; returns the estimate and diagnostics (see TrackResult)."""
        t_start = time.perf_counter()
        stage_ms: dict[str, float] = {}
        searchable = valid_box(frame.box) is not None or frame.region is not None
        t0 = time.perf_counter()
        if not self.initialised:
            if not searchable:
                return self._result(None, {"total": ms_since(t_start)})
            self._initialise(frame)
            stage_ms["init"] = ms_since(t0)
        else:
            self._predict()
            stage_ms["predict"] = ms_since(t0)
            if not searchable:
                stage_ms["total"] = ms_since(t_start)
                return self._result(None, stage_ms)

        weighed = self._weigh(frame, stage_ms)

        t0 = time.perf_counter()
        weights = weighed.weights
        if weights.W is None:
            self.warner.collapse()
            weighed = weighed._replace(alpha=1.0)
            if self.estimate is None:  # nothing better: the mean of the (uninformed) particles
                self.estimate = self._estimate(np.full(self.n, 1.0 / self.n))
        else:
            self.weights = weights.W
            self.estimate = self._estimate(weights.W)
        stage_ms["estimate"] = ms_since(t0)

        t0 = time.perf_counter()
        self._resample(frame, weights, weighed.alpha)
        stage_ms["resample"] = ms_since(t0)
        stage_ms["total"] = ms_since(t_start)
        return self._result(weighed, stage_ms)

    def _resample(self, frame: Frame, weights: Weights, alpha: float) -> None:
        """New particle set: N - round(alpha N) from the belief (N with ``keep_belief`` unless
        the weights collapsed), and round(alpha N) from ``_draw``."""
        n_cand = round(alpha * self.n)
        n_belief = self.n if (self.keep_belief and weights.W is not None) else self.n - n_cand
        parts: list[Particles] = []
        if n_belief > 0:
            assert weights.W is not None  # a collapse has alpha 1
            parts.append(self._take(self.resample_indices(weights.W, n_belief, self.rng)))
        if n_cand > 0:
            parts.append(self._draw(frame, n_cand))
        self._assign(tuple(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))
        total = n_belief + n_cand
        self.weights = np.full(total, 1.0 / total)
        self.fresh = np.arange(total) >= n_belief

    def _result(self, weighed: Weighed | None, stage_ms: dict[str, float]) -> TrackResult:
        est = self.estimate
        return TrackResult(
            R=None if est is None else est[0].copy(),
            t=None if est is None else est[1].copy(),
            alpha=_NAN if weighed is None else float(weighed.alpha),
            sum_L=_NAN if weighed is None else float(weighed.sum_L),
            sum_C=_NAN if weighed is None else float(weighed.sum_C),
            ess=_NAN if weighed is None else weighed.weights.ess,
            stage_ms=stage_ms,
            ok=est is not None,
            weighed=weighed is not None,
        )
