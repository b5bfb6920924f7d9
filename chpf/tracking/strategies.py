"""Reinvigoration strategies of the 6D particle filter: each decides alpha, the fraction of
particles drawn from the candidate distribution at a frame's resampling.

Every strategy has ``alpha(scores, weights=None, fresh=None) -> float`` in [0, 1] (``weights``
(N,): the frame's normalised importance weights, None when they collapsed; ``fresh`` (N,) bool:
the particles drawn from phi_cand or a proposal at the previous resampling, None when unknown;
only CH-PF uses them) and ``reset()`` (forget its state at the start of a sequence). Two
attributes let a strategy change the core's loop without a special filter class: ``betas``
(annealing layers, one weighing per entry; the default (1.0,) is one ordinary weighing) with
``layer_decay`` (diffusion scale factor per layer), and ``propose(frame, n, rng, likelihood)``
(where reinvigorated particles come from; None means phi_cand). CH-PF also changes how the
particles weigh (``importance(scores)``: the likelihood's w; for CH-PF tempered by the last
alpha and times (1 - C)^k) and,
with ``keeps_belief``, whether the drawn particles replace part of the belief or join all of it.

A strategy with options takes its config dataclass (defined next to it; the defaults live
there and nowhere else); chpf.tracking.methods registers each one under its method name.
"""

from __future__ import annotations

import itertools
import typing
from dataclasses import dataclass
from typing import Literal

import numpy as np

from chpf.config_schema import Invalid, Section, setting
from chpf.errors import ConfigError
from chpf.geometry import perturb_rotations
from chpf.tracking.types import Frame, Reference, Scores, SingleFrameEstimator


def _finite(x: np.ndarray) -> np.ndarray:
    """Float64 copy with NaN/inf replaced by 0."""
    return np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)


class Strategy:
    """Base strategy: no reinvigoration, one weighing per frame, candidates from phi_cand."""

    name = "none"
    betas: tuple[float, ...] = (1.0,)
    layer_decay: float = 1.0
    keeps_belief: bool = False  # True: round(alpha N) drawn particles join N from the belief

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        """Reinvigoration rate for this frame's resampling (see the module docstring)."""
        return 0.0

    def importance(self, scores: Scores) -> np.ndarray:
        """Importance weights (N,) of scored particles: the likelihood's w."""
        return scores.w

    def reset(self) -> None:
        """Forget any state (start of a new sequence)."""

    def propose(
        self, frame: Frame, n: int, rng: np.random.Generator, likelihood: object
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """n reinvigorated poses (R (n,3,3), t (n,3)), or None to use phi_cand."""
        return None


class NoReinvigoration(Strategy):
    """alpha = 0: a plain SIR particle filter."""

    name = "none"


@dataclass
class FixedConfig(Section):
    """Method "fixed": rate, the constant alpha."""

    rate: float = setting(0.1, ge=0.0, le=1.0)


class FixedRate(Strategy):
    """alpha = a constant fraction."""

    name = "fixed"

    def __init__(self, config: FixedConfig | None = None) -> None:
        self.rate = (config or FixedConfig()).rate

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        return self.rate


CMode = Literal["learned", "depth", "both", "none"]
C_MODES: tuple[str, ...] = typing.get_args(CMode)
"""Where C comes from: the learned classifier, C_depth, their mean, or nowhere (C = None)."""


CHPFSums = Literal["paper", "belief", "weighted"]
CHPF_SUMS: tuple[str, ...] = typing.get_args(CHPFSums)
"""Which particles CH-PF's alpha = S_C / (S_C + S_L) sums over: "paper" every particle of the
set, as in the paper's figure (also those just drawn from phi_cand); "belief" only those
resampled from the belief at the previous frame (all when every particle is fresh); "weighted"
every particle weighed by its normalised importance weight w_i: S_X = sum_i w_i X_i = E_w[X]
(all alike when the weights collapsed)."""


CHPFReference = Literal["none", "detection", "box"]
CHPF_REFERENCES: tuple[str, ...] = typing.get_args(CHPFReference)
"""What CH-PF's alpha measures the set's L and C against: "none" their values as they are (the
paper's); "detection" the frame's own best hypothesis at the detection box (Scores.reference,
relative_scores): the set is in doubt when it explains the frame worse than that hypothesis
does, not when the frame shows little of the object; "box" the same, and on a frame without a
detection the best hypothesis at the search region's box around the estimate while the region
is not widened (Frame.cue_box; chpf.tracking.search_region): with the first box only, the
values as they are read an occluded object as a lost one and widened the search around a set
that was on it. Frames without such a box use the values as they are."""


def either(C: np.ndarray, other: np.ndarray | None) -> np.ndarray:
    """Counter-evidence (N,) from two independent sources in [0, 1]: 1 - (1 - C)(1 - other);
    C itself when other is None."""
    return C if other is None else 1.0 - (1.0 - C) * (1.0 - other)


def relative_scores(
    L: np.ndarray, C: np.ndarray, reference: Reference
) -> tuple[np.ndarray, np.ndarray]:
    """L (N,) and C (N,) in [0, 1] relative to the frame's reference (L_ref, C_ref):
    L' = min(L / L_ref, 1), the share of the best hypothesis' support that a particle has;
    C' = clip((C - C_ref) / (1 - C_ref), 0, 1), its counter-evidence beyond what even that
    hypothesis gets (occluders, clutter)."""
    L_ref, C_ref = reference
    L_rel = np.minimum(L / max(L_ref, 1e-6), 1.0)
    C_rel = np.clip((C - C_ref) / max(1.0 - C_ref, 1e-6), 0.0, 1.0)
    return L_rel, C_rel


BoxShape = Literal["gauss", "ramp"]
BOX_SHAPES: tuple[str, ...] = typing.get_args(BoxShape)
"""How the box-scale counter-evidence C_box grows with r = ln(box side / projected side) > 0
(a hypothesis that would project smaller than the detection box; chpf.tracking.bundle_likelihood):
"gauss" 1 - exp(-r^2 / (2 s^2)), the detector's log-size noise s; "ramp" clip((rho - 1 - m) / m,
0, 1), nothing below a margin m of the ratio rho."""


BoxSides = Literal["larger", "each"]
BOX_SIDES: tuple[str, ...] = typing.get_args(BoxSides)
"""Which sides of the box the box-scale counter-evidence compares with the projection's:
"each" width with width and height with height, "larger" the larger of each."""


SilhouetteCue = Literal["edges", "region"]
SILHOUETTE_CUES: tuple[str, ...] = typing.get_args(SilhouetteCue)
"""What ``c_silhouette`` measures of a hypothesis's projected outline (chpf.tracking.silhouette):
"edges" how well it meets the image's intensity edges (SilhouetteEdges); "region" how well it
separates the colours inside it from those around it (SilhouetteRegion)."""


@dataclass
class CHPFConfig(Section):
    """CH-PF: c_mode, where the Counter-Hypothetical likelihood C comes from (C_MODES; depth
    and both need RGB-D); sums, which particles alpha's sums run over (CHPF_SUMS); l_power,
    the exponent p of L in those sums (S_L sums L^p; 1 = the paper's L); c_box, the scale (s or
    m) of the box-scale counter-evidence added to C (None = none; chpf.tracking.bundle_likelihood)
    and c_box_shape its shape (BOX_SHAPES); c_box_sides, which sides of the box it reads
    (BOX_SIDES: "each" width and height, "larger" the larger side); box_whole, the probability
    q that a side of the box is the whole object's, which weighs a hypothesis projecting larger
    than that side by 1 - q C_box (None = off); c_edge, the margin of the box-edge
    counter-evidence (Scores.C_edge; None = off), which alpha counts and the weights do not;
    c_near, the margin of the too-near counter-evidence that joins C_edge (None = off);
    edge_discounts_l, whether alpha's L side sums L (1 - C_edge): support that the box's edges
    contradict does not count;
    c_silhouette, the power p of the silhouette's counter-evidence 1 - (a / max a)^p added to C
    (chpf.tracking.silhouette; None = off) and silhouette_cue what a measures (SILHOUETTE_CUES);
    c_weight, the exponent k of the importance weights w (1 - C)^k (0 = the paper's: C only
    sets alpha); keep_belief, the round(alpha N) particles drawn from phi_cand join N resampled
    from the belief (N + round(alpha N) weighed at the next frame) instead of replacing
    round(alpha N) of them (false = the paper's); temper, how much the set's doubt flattens the
    likelihood's weights: w^(1 - temper d_prev), d_prev the previous frame's doubt S_C / (S_C +
    S_L) of the values as they are (0 = the paper's: w as it is); reference, what alpha
    measures L and C against (CHPF_REFERENCES; "none" = the paper's); reference_anchors, the
    sides (times the detection's longer side) of the whole-object boxes whose crops the
    reference's C also reads, were the detection only the visible part (empty: the box's own
    crop only; chpf.tracking.bundle_likelihood, item 8)."""

    c_mode: CMode = "learned"
    sums: CHPFSums = "weighted"
    l_power: float = setting(3.0, gt=0.0)
    c_box: float | None = setting(0.1, gt=0.0)
    c_box_shape: BoxShape = "gauss"
    c_box_sides: BoxSides = "larger"
    box_whole: float | None = setting(None, gt=0.0, le=1.0)
    c_edge: float | None = setting(0.2, gt=0.0)
    c_near: float | None = setting(0.05, gt=0.0)
    edge_discounts_l: bool = True
    c_silhouette: float | None = setting(1.0, gt=0.0)
    silhouette_cue: SilhouetteCue = "region"
    c_weight: float = setting(1.0, ge=0.0)
    keep_belief: bool = True
    temper: float = setting(1.0, ge=0.0, le=1.0)
    reference: CHPFReference = "box"
    reference_anchors: tuple[float, ...] = (1.0, 1.4)

    def check(self) -> None:
        if any(not a > 0 for a in self.reference_anchors):
            raise Invalid("reference_anchors", f"must be > 0, got {list(self.reference_anchors)}")


class CHPF(Strategy):
    """Counter-Hypothetical PF: alpha = S_C / (S_C + S_L), the sums as chosen by
    ``config.sums`` (CHPF_SUMS; "paper": sum C / (sum C + sum L) over every particle), S_L
    summing L ** ``config.l_power``, L and C relative to the frame's reference when
    ``config.reference`` asks for it and the frame has one (relative_scores), and with
    ``config.edge_discounts_l`` each L times 1 - C_edge (the box's edges contradict it).

    The same ratio of the values as they are is the set's doubt, which ``temper`` reads: a
    frame that shows little of the object is one to trust the likelihood less on, not one to
    reinvigorate on. When both sums are 0 (no evidence for nor against any particle) the ratio
    is 1.
    """

    name = "chpf"

    def __init__(self, config: CHPFConfig | None = None) -> None:
        self.config = config or CHPFConfig()
        self.last_doubt = 0.0  # the previous frame's doubt (``temper``)

    def reset(self) -> None:
        self.last_doubt = 0.0

    @property
    def keeps_belief(self) -> bool:
        """The ``keep_belief`` option."""
        return self.config.keep_belief

    def importance(self, scores: Scores) -> np.ndarray:
        """w ** (1 - temper d_prev) (1 - C) ** c_weight (d_prev: the last frame's doubt). The
        evidence against a particle weighs it down: L alone barely tells a pose 0.3 diameters off
        from one within 0.1 (their mean L 0.67 and 0.70 on the development suite), C does (0.43 and
        0.10). And a set in doubt trusts the likelihood less: when most of the object is hidden, a
        sharp w hands the set to whichever particle best matches the visible sliver. C's factor is
        not tempered: flattening it too let doubt feed itself (flat weights, a wider set, more
        doubt) until alpha sat at 0.99 (docs/chpf-ablations.md)."""
        w = scores.w
        if self.config.temper > 0.0:
            w = np.asarray(w, dtype=np.float64) ** (1.0 - self.config.temper * self.last_doubt)
        if self.config.c_weight <= 0.0 or scores.C is None:
            return w
        keep = np.clip(1.0 - _finite(scores.C), 1e-6, 1.0)
        return w * keep**self.config.c_weight

    def _counts(self, n: int, weights: np.ndarray | None, fresh: np.ndarray | None) -> np.ndarray:
        """What each of the n particles counts in the sums (n,)."""
        if self.config.sums == "weighted" and weights is not None:
            return _finite(weights).clip(min=0.0)
        if self.config.sums == "belief" and fresh is not None and not np.all(fresh):
            return (~np.asarray(fresh, dtype=bool)).astype(np.float64)
        return np.ones(n)

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        if scores.C is None:
            raise ConfigError("CH-PF needs a Counter-Hypothetical likelihood C (none was given)")
        C = either(_finite(scores.C).clip(min=0.0), scores.C_edge)
        L = _finite(scores.L).clip(min=0.0)
        k = self._counts(C.shape[0], weights, fresh)
        self.last_doubt = self._ratio(k, L, C)
        if self.config.reference != "none" and scores.reference is not None:
            L, C = relative_scores(L, C, scores.reference)
        if self.config.edge_discounts_l and scores.C_edge is not None:
            L = L * (1.0 - scores.C_edge)
        return self._ratio(k, L, C)

    def _ratio(self, k: np.ndarray, L: np.ndarray, C: np.ndarray) -> float:
        """S_C / (S_C + S_L) of L (N,), C (N,) counted k (N,) (1 when both sums are 0)."""
        sum_c = float(k @ C)
        sum_l = float(k @ L**self.config.l_power)
        total = sum_c + sum_l
        return 1.0 if total <= 0.0 else sum_c / total


@dataclass
class SRLConfig(Section):
    """SRL: beta, the mean unnormalised likelihood L regarded as "good"."""

    beta: float = setting(0.6, gt=0.0)


class SRL(Strategy):
    """Sensor Resetting Localisation: alpha = clip(1 - mean(L) / beta, 0, 1).

    beta: the unnormalised likelihood (minimum cosine similarity) regarded as "good".
    """

    name = "srl"

    def __init__(self, config: SRLConfig | None = None) -> None:
        self.beta = (config or SRLConfig()).beta

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        mean_l = float(_finite(scores.L).mean()) if np.size(scores.L) else 0.0
        return float(np.clip(1.0 - mean_l / self.beta, 0.0, 1.0))


@dataclass
class AugMCLConfig(Section):
    """Aug. MCL: the smoothing rates of the slow and fast likelihood averages."""

    a_slow: float = 0.001
    a_fast: float = 0.1

    def check(self) -> None:
        if not 0.0 < self.a_slow < self.a_fast <= 1.0:
            raise Invalid(
                "a_slow", f"needs 0 < a_slow < a_fast <= 1, got {self.a_slow}, {self.a_fast}"
            )


class AugMCL(Strategy):
    """Augmented MCL: w_avg = mean(L); w_slow += a_slow (w_avg - w_slow);
    w_fast += a_fast (w_avg - w_fast); alpha = max(0, 1 - w_fast / w_slow).

    Both averages start at the first frame's w_avg (so alpha = 0 on the first frame).
    """

    name = "augmcl"

    def __init__(self, config: AugMCLConfig | None = None) -> None:
        config = config or AugMCLConfig()
        self.a_slow = config.a_slow
        self.a_fast = config.a_fast
        self.w_slow: float | None = None
        self.w_fast: float | None = None

    def reset(self) -> None:
        self.w_slow = None
        self.w_fast = None

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        w_avg = float(_finite(scores.L).mean()) if np.size(scores.L) else 0.0
        if self.w_slow is None or self.w_fast is None:
            self.w_slow = self.w_fast = w_avg
        else:
            self.w_slow += self.a_slow * (w_avg - self.w_slow)
            self.w_fast += self.a_fast * (w_avg - self.w_fast)
        if self.w_slow <= 0.0:
            return 1.0 if self.w_fast <= 0.0 else 0.0
        return float(max(0.0, 1.0 - self.w_fast / self.w_slow))


@dataclass
class AnnealingConfig(Section):
    """Annealing: betas, the layers' exponents (rising, ending at 1.0); decay, the diffusion
    scale factor per layer."""

    betas: tuple[float, ...] = (0.2, 0.5, 1.0)
    decay: float = setting(0.5, gt=0.0, le=1.0)

    def check(self) -> None:
        betas = self.betas
        if not betas or betas[-1] != 1.0 or any(b <= 0 for b in betas):
            raise Invalid("betas", f"must be positive and end at 1.0, got {list(betas)}")
        if any(b2 < b1 for b1, b2 in itertools.pairwise(betas)):
            raise Invalid("betas", f"must rise, got {list(betas)}")


class Annealing(Strategy):
    """Annealed particle filter (no reinvigoration): M layers per frame; layer m weighs with
    w ** betas[m] (betas rising to 1), resamples, and diffuses with the motion model scaled by
    layer_decay ** (m + 1) before the next layer."""

    name = "annealing"

    def __init__(self, config: AnnealingConfig | None = None) -> None:
        config = config or AnnealingConfig()
        self.betas = tuple(float(b) for b in config.betas)
        self.layer_decay = float(config.decay)


@dataclass
class E2EConfig(Section):
    """MCL + E2E: rate, the fraction drawn around the single-frame estimate; sigma_t its
    translation std (x, y, z) metres; sigma_r its rotation std (axis-angle) radians."""

    rate: float = setting(0.2, ge=0.0, le=1.0)
    sigma_t: tuple[float, float, float] = setting((0.01, 0.01, 0.03), ge=0.0)
    sigma_r: float = setting(0.15, ge=0.0)


class E2E(Strategy):
    """MCL + E2E: a fixed fraction of particles drawn from a Gaussian around a single-frame
    estimate (the likelihood's ``single_frame_estimate``); phi_cand when it gives none."""

    name = "e2e"

    def __init__(self, config: E2EConfig | None = None) -> None:
        config = config or E2EConfig()
        self.rate = float(config.rate)
        self.sigma_t = np.asarray(config.sigma_t, dtype=np.float64)
        self.sigma_r = float(config.sigma_r)

    def alpha(
        self, scores: Scores, weights: np.ndarray | None = None, fresh: np.ndarray | None = None
    ) -> float:
        return self.rate

    def propose(
        self, frame: Frame, n: int, rng: np.random.Generator, likelihood: object
    ) -> tuple[np.ndarray, np.ndarray] | None:
        if n <= 0 or not isinstance(likelihood, SingleFrameEstimator):
            return None
        est = likelihood.single_frame_estimate(frame)
        if est is None:
            return None
        R0, t0 = (np.asarray(a, dtype=np.float64) for a in est)
        R = perturb_rotations(np.broadcast_to(R0, (n, 3, 3)), self.sigma_r, rng)
        t = t0[None, :] + rng.standard_normal((n, 3)) * self.sigma_t
        return R, t
