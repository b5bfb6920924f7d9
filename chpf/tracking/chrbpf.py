"""CH-RBPF: PoseRBPF's Rao-Blackwellised filter with CH-PF's adaptive reinvigoration.

Each translation particle t_i hypothesises the most probable codebook entry k_i of its
orientation posterior. Its C_i is the classifier's probability that (the crop at t_i, entry k_i)
is misaligned, its L_i = max(cos_ik_i, 0); alpha is CH-PF's rule (``chpf.tracking.strategies.CHPF``
with the ``chpf`` options: which particles the sums run over, the power of L) over them, with
the particles' normalised weights and the ones drawn at the last resampling. alpha replaces
PoseRBPF's threshold reset and PoseRBPF++'s fixed share; a collapse reinvigorates all. The
reinvigorated particles come from phi_cand with uniform orientation distributions, as
PoseRBPF's. C is the learned one whatever ``chpf.c_mode`` says. CH-PF's other options act
here as there: ``temper`` and ``c_weight`` k turn each particle's PoseRBPF weight w_i into
w_i^(1 - temper alpha_prev) (1 - C_i)^k, and ``keep_belief`` lets the drawn particles join N
resampled from the belief.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from chpf.errors import ConfigError
from chpf.tracking.filter_loop import Weighed
from chpf.tracking.rbpf import RaoBlackwellisedFilter
from chpf.tracking.resampling import Weights
from chpf.tracking.strategies import CHPF
from chpf.tracking.timing import ms_since
from chpf.tracking.types import CodebookLikelihood, CodebookScores, Scores


class CHRBPF(RaoBlackwellisedFilter):
    """CH-RBPF (module docstring): ``rule`` gives alpha; the other keywords are
    RaoBlackwellisedFilter's (its reset_threshold and reinvigorate are not used)."""

    def __init__(self, likelihood: CodebookLikelihood, rule: CHPF, **kwargs: Any) -> None:
        self.rule = rule
        super().__init__(likelihood, name="chrbpf", **kwargs)

    def reset(self) -> None:
        """Forget the particles, the estimate and the rule's state."""
        super().reset()
        self.rule.reset()

    @property
    def keep_belief(self) -> bool:  # type: ignore[override]
        """The rule's choice (``CHPF.keeps_belief``), or a frame whose draws come from a probe
        that took over (``RaoBlackwellisedFilter``)."""
        return self.rule.keeps_belief or self._searching

    def _reinvigoration(
        self,
        cs: CodebookScores,
        cos: np.ndarray,
        weights: Weights,
        stage_ms: dict[str, float],
    ) -> Weighed:
        assert self.P is not None
        if cs.misaligned is None:
            raise ConfigError("CH-RBPF needs a Counter-Hypothetical likelihood C (none was given)")
        k = np.argmax(self.P, axis=1)
        L = np.clip(cos[np.arange(k.shape[0]), k], 0.0, None).astype(np.float64)
        t0 = time.perf_counter()
        C = np.asarray(cs.misaligned(k), dtype=np.float64)
        stage_ms["head"] = ms_since(t0)
        if weights.W is None:
            return Weighed(weights, 1.0, float(L.sum()), float(C.sum()))
        weights = Weights.from_weights(self.rule.importance(Scores(L=L, w=weights.W, C=C)))
        W = weights.W  # positive: (1 - C) and the tempering keep every weight above 0
        assert W is not None
        C_edge = cs.edge(k) if cs.edge is not None else None
        scores = Scores(L=L, w=W, C=C, reference=cs.reference, C_edge=C_edge)
        alpha = self.rule.alpha(scores, W, self.fresh)
        return Weighed(weights, float(np.clip(alpha, 0.0, 1.0)), float(L.sum()), float(C.sum()))
