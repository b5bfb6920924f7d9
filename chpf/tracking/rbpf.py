"""PoseRBPF and PoseRBPF++: Rao-Blackwellised particle filters (Deng et al., RSS 2019).

The particles are translations t (N,3) metres; each carries a probability vector (K,) over
the codebook's allocentric orientations. Per frame with a box:

- predict: random walk on t; each orientation distribution is diffused over the grid with a
  precomputed sparse neighbour matrix (the rotation prior);
- weigh: cosine similarities c (N,K) of each particle's crop embedding with the whole
  codebook; orientation likelihood exp(-(1 - c)^2 / (2 sigma^2)); posterior = likelihood x
  prior (normalised per particle); particle weight = sum_k likelihood x prior (times a depth
  factor for RGB-D, when the likelihood gives one);
- estimate: weighted mean translation; orientation = the grid entry at the argmax of the
  weighted mixture of the particles' distributions (or the quaternion mean of the entries
  around it, ``rotation_estimate="mean"``), allocentric -> egocentric at the estimated t;
- resample: systematic; PoseRBPF++ draws ``reinvigorate`` (0.5) of the particles from phi_cand
  (uniform orientation distribution) every frame; both reset all particles from phi_cand when
  the best similarity of the frame drops below ``reset_threshold``;
- a frame without a detection whose search region is a probe that took over
  (``Frame.region.probed``: chpf.tracking.search_region widens the window after ``patience``
  frames in a row whose likelihood says lost, scans it with probes and lets one take over when
  it beats the estimate and the remembered look-alikes) draws at least ``search_fraction`` of N
  from phi_cand, i.e. around that probe, and they join the N particles resampled from the belief
  (a wrong draw dies at the next weighing, a right one takes over). Without it PoseRBPF draws
  only on its reset, which a lost filter's similarity rarely triggers (the widened search then
  never reaches the filter).

Recorded: L_i = max(max_k c_ik, 0) (sum_L), alpha = fraction of particles drawn from phi_cand.
"""

from __future__ import annotations

import time

import numpy as np

from chpf.geometry import (
    RotationGrid,
    allocentric_to_egocentric,
    average_quaternions,
    geodesic_angle,
    quat_to_matrix,
)
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.filter_loop import FilterLoop, Particles, Weighed
from chpf.tracking.motion import RandomWalk
from chpf.tracking.resampling import Weights
from chpf.tracking.rotation_diffusion import grid_spacing, neighbour_matrix
from chpf.tracking.timing import add_ms, ms_since
from chpf.tracking.types import CodebookLikelihood, CodebookScores, Frame


class RaoBlackwellisedFilter(FilterLoop):
    """PoseRBPF (``reinvigorate=0``) / PoseRBPF++ (``reinvigorate=0.5``); see module docstring.

    sigma: width of the cosine-to-likelihood map. rotation_sigma: rad, Gaussian kernel of the
    rotation prior (None = the grid spacing); n_neighbours: grid neighbours per entry.
    reset_threshold: best cosine similarity below which every particle is redrawn.
    search_fraction: the least share drawn from phi_cand on a frame whose search region is a
    probe that took over, joining the belief (module docstring; 0: off).
    resampling: a scheme of ``chpf.tracking.resampling.RESAMPLERS``.
    """

    def __init__(
        self,
        likelihood: CodebookLikelihood,
        n_particles: int = 50,
        motion: RandomWalk | None = None,
        candidates: CandidateSampler | None = None,
        rng: np.random.Generator | None = None,
        sigma: float = 0.1,
        rotation_sigma: float | None = None,
        n_neighbours: int = 12,
        reset_threshold: float = 0.4,
        reinvigorate: float = 0.0,
        search_fraction: float = 0.5,
        rotation_estimate: str = "argmax",
        name: str = "poserbpf",
        resampling: str = "systematic",
    ) -> None:
        if rotation_estimate not in ("argmax", "mean"):
            raise ValueError(f"rotation_estimate: 'argmax' or 'mean', got {rotation_estimate!r}")
        super().__init__(n_particles, rng, f"RaoBlackwellisedFilter[{name}]", resampling)
        self.likelihood = likelihood
        self.grid: RotationGrid = likelihood.grid  # type: ignore[assignment]
        self.k = len(self.grid)
        self.motion = motion or RandomWalk()
        self.candidates = candidates or CandidateSampler()
        self.sigma = float(sigma)
        self.reset_threshold = float(reset_threshold)
        self.reinvigorate = float(reinvigorate)
        self.search_fraction = float(search_fraction)
        self.rotation_estimate = rotation_estimate
        self.name = name
        rot_sigma = rotation_sigma if rotation_sigma is not None else grid_spacing(self.grid)
        # float32 throughout the (N,K) arrays: K is ~20k, these dominate the filter's time
        self.diffusion = neighbour_matrix(self.grid, n_neighbours, rot_sigma).astype(np.float32)
        self._mean_radius = 2.0 * rot_sigma
        self.reset()

    def reset(self) -> None:
        """Forget the particles and the estimate."""
        super().reset()
        self.t: np.ndarray | None = None
        self.P: np.ndarray | None = None  # (N, K) orientation distributions
        self.n_resets = 0
        self._searching = False  # this frame's draws come from a probe that took over

    @property
    def keep_belief(self) -> bool:  # type: ignore[override]
        """True on a frame whose draws come from a probe that took over (module docstring)."""
        return self._searching

    @property
    def initialised(self) -> bool:
        return self.t is not None

    def set_particles(self, t: np.ndarray, P: np.ndarray | None = None) -> None:
        """Replace the translation particles (n,3) and their distributions (n,K) (None: uniform)."""
        self.t = np.array(t, dtype=np.float64).reshape(-1, 3)
        n = len(self.t)
        self.P = (
            np.full((n, self.k), 1.0 / self.k, np.float32)
            if P is None
            else np.array(P, dtype=np.float32).reshape(n, self.k)
        )
        self.weights = np.full(n, 1.0 / n)
        self.fresh = np.zeros(n, dtype=bool)

    def _rotation(self, p: np.ndarray) -> np.ndarray:
        """Allocentric rotation (3,3) from a distribution p (K,) over the grid."""
        k_best = int(np.argmax(p))
        if self.rotation_estimate == "argmax":
            return self.grid.rotations[k_best]
        near = geodesic_angle(self.grid.rotations[k_best], self.grid.rotations) < self._mean_radius
        return quat_to_matrix(average_quaternions(self.grid.quats[near], p[near]))

    # ------------------------------------------------------------------ FilterLoop hooks
    def _initialise(self, frame: Frame) -> None:
        self.set_particles(self.candidates.translations(self.n, frame, self.rng))
        self.fresh = np.ones(self.n, dtype=bool)

    def _predict(self) -> None:
        assert self.t is not None and self.P is not None
        self.t = self.motion.predict_translation(self.t, self.rng)
        self.P = np.asarray(self.P @ self.diffusion)

    def _weigh(self, frame: Frame, stage_ms: dict[str, float]) -> Weighed:
        """Posterior orientation distributions into ``P``; particle weights sum_k lik x prior."""
        assert self.t is not None and self.P is not None
        t0 = time.perf_counter()
        cs = self.likelihood.codebook_scores(frame, self.t)
        stage_ms["likelihood"] = ms_since(t0)
        add_ms(stage_ms, cs.stage_ms)

        t0 = time.perf_counter()
        cos = np.asarray(cs.cos, dtype=np.float32)
        if np.isnan(cos).any():  # (np.nan_to_num on every frame costs more than all the rest)
            cos = np.where(np.isnan(cos), np.float32(-1.0), cos)
        post = 1.0 - cos  # in place below: exp(-(1 - c)^2 / (2 sigma^2)) * prior
        post *= post
        post *= np.float32(-0.5 / self.sigma**2)
        np.exp(post, out=post)
        post *= self.P
        row = post.sum(axis=1).astype(np.float64)  # sum_k likelihood x prior
        wi = row.copy()
        if frame.depth is not None:
            dw = self.likelihood.depth_weight(frame, np.argmax(post, axis=1), self.t)
            if dw is not None:
                wi *= np.asarray(dw, dtype=np.float64)
        empty = row <= 0
        post /= np.where(empty, 1.0, row).astype(np.float32)[:, None]
        post[empty] = 1.0 / self.k
        self.P = post
        weights = Weights.from_weights(wi)
        stage_ms["weigh"] = ms_since(t0)
        return self._searched(frame, self._reinvigoration(cs, cos, weights, stage_ms))

    def _searched(self, frame: Frame, weighed: Weighed) -> Weighed:
        """``weighed`` with alpha raised to ``search_fraction`` on a frame whose search region is
        a probe that took over (the drawn particles then join the belief: ``keep_belief``); a
        reset or a collapse stays as it is."""
        region = frame.region
        widened = region is not None and region.probed and frame.box is None
        self._searching = bool(
            widened
            and weighed.weights.W is not None
            and weighed.alpha < 1.0
            and self.search_fraction > 0.0
        )
        if self._searching and weighed.alpha < self.search_fraction:
            return weighed._replace(alpha=self.search_fraction)
        return weighed

    def _reinvigoration(
        self,
        cs: CodebookScores,
        cos: np.ndarray,
        weights: Weights,
        stage_ms: dict[str, float],
    ) -> Weighed:
        """The frame's Weighed with its alpha: PoseRBPF's reset (all particles redrawn when the
        best cosine of the frame is below ``reset_threshold`` or the weights collapsed), else
        ``reinvigorate``. cos (N,K): this frame's similarities; P already holds the posterior."""
        best = cos.max(axis=1)
        best_sim = float(best.max()) if best.size else -1.0
        reset = weights.collapsed or best_sim < self.reset_threshold
        self.n_resets += int(reset)
        alpha = 1.0 if reset else self.reinvigorate
        return Weighed(weights, alpha, float(np.clip(best, 0.0, None).sum()))

    def _estimate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean t; rotation from the weighted mixture of the distributions."""
        assert self.t is not None and self.P is not None
        t_est = w @ self.t
        R_allo = self._rotation(w.astype(np.float32) @ self.P)
        return allocentric_to_egocentric(R_allo, t_est), t_est

    def _take(self, idx: np.ndarray) -> Particles:
        assert self.t is not None and self.P is not None
        return self.t[idx], self.P[idx]

    def _draw(self, frame: Frame, n: int) -> Particles:
        """Translations from phi_cand (at the belief's scale when the detection is its visible
        part: ``CandidateSampler.visible_part``) with uniform orientation distributions."""
        return (
            self.candidates.translations(n, frame, self.rng, self.estimate),
            np.full((n, self.k), 1.0 / self.k, np.float32),
        )

    def _assign(self, particles: Particles) -> None:
        self.t, self.P = particles
