"""Data types shared by the likelihoods and the filters: frames, scores, per-frame results."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

Box = tuple[float, float, float, float]
"""A 2D detection box (x, y, w, h) in pixels (x, y = top-left corner)."""


@dataclass(frozen=True)
class Region:
    """A search region of a frame without a detection (chpf.tracking.search_region).

    box (x, y, w, h) pixels: where the object is looked for, at its projected size: the model's
    projected bounding box at the current estimate, or, once the region is widened, the probe
    box that took over (chpf.tracking.search_region; phi_cand's depth rule and box-centre
    look-up read it as they read a detection's box). area (x, y, w, h) pixels: where
    phi_cand's candidates lie: the window, around the probe that took over, or around the
    estimate's box when no probe did. window (x, y, w, h) pixels: the part of the
    image searched: the estimate's box enlarged by the margin, times ``scale``, clipped.
    scale >= 1: the widening phi_cand draws in (1 = not widened, or widened but no probe took
    over: phi_cand draws around the estimate). cue: the box's crop may inform phi_cand's
    orientations and E2E's single-frame estimate (False in a widened window without probes).
    probed: the box is a probe that took over (the Rao-Blackwellised filters then draw there).
    fitted: the box was fitted to the image (the estimate moved along its ray to where its
    outline's colour contrast peaks: chpf.tracking.search_region), a measurement of the
    object's size that CH-PF's box scale reads as it reads a detection's (``Frame.scale_box``).
    """

    box: Box
    area: Box
    window: Box
    scale: float = 1.0
    cue: bool = True
    probed: bool = False
    fitted: bool = False


@dataclass
class Frame:
    """One camera frame: rgb (H,W,3) uint8, depth (H,W) float32 m (0 = missing) or None,
    K (3,3) OpenCV intrinsics, box (x, y, w, h) pixels of the object's detection or None,
    region: where to search when there is no detection (None: predict only)."""

    rgb: np.ndarray
    depth: np.ndarray | None
    K: np.ndarray
    box: Box | None = None
    region: Region | None = None

    def cue_box(self) -> Box | None:
        """The box whose centre crop informs phi_cand's orientations and MCL + E2E's
        single-frame estimate: the detection, else the search region's box when it may
        (``Region.cue``); not checked."""
        if self.box is not None:
            return self.box
        return self.region.box if self.region is not None and self.region.cue else None

    def scale_box(self) -> Box | None:
        """The box that measures the object's size in the image (CH-PF's box scale,
        chpf.tracking.bundle_likelihood, item 6): the detection, else a fitted search region's
        box (``Region.fitted``); not checked."""
        if self.box is not None:
            return self.box
        return self.region.box if self.region is not None and self.region.fitted else None


Reference = tuple[float, float]
"""(L_ref, C_ref): L and C of the frame's own best hypothesis, the codebook entry that best
matches the crop at the detection box's centre (chpf.tracking.bundle_likelihood, item 8): what
a pose can score on this frame's view of the object, against which CH-PF measures its set's
(chpf.tracking.strategies.relative_scores)."""


@dataclass
class Scores:
    """What a likelihood returns for N pose hypotheses of one frame.

    L: (N,) unnormalised likelihood in [0, 1] (used by SRL, Aug. MCL, CH-PF).
    w: (N,) importance weights (>= 0, not normalised).
    C: (N,) Counter-Hypothetical likelihood in [0, 1] (probability of misalignment) or None.
    stage_ms: milliseconds spent per stage (e.g. "crop", "encode", "head").
    R: (N,3,3) the orientations that were scored when the likelihood moved them (its
    orientation search), which the filter adopts; None when it scored the given ones.
    reference: (L_ref, C_ref), the frame's reference scores (``Reference``), or None.
    C_edge: (N,) in [0, 1] the box-edge counter-evidence, too-near included
    (chpf.tracking.bundle_likelihood, item 6), which counts in CH-PF's alpha but not in C's
    weighing, or None.
    """

    L: np.ndarray
    w: np.ndarray
    C: np.ndarray | None = None
    stage_ms: dict[str, float] = field(default_factory=dict)
    R: np.ndarray | None = None
    reference: Reference | None = None
    C_edge: np.ndarray | None = None


@dataclass
class CodebookScores:
    """Similarities of N translation hypotheses with the whole orientation codebook.

    cos: (N, K) cosine similarity of the observed crop at each translation with every codebook
    entry (allocentric orientations of ``grid``). stage_ms as in Scores. misaligned: the
    learned C (N,) of one codebook entry per particle, idx (N,) int -> (N,) (None when the
    likelihood has no classifier; CH-RBPF calls it). reference: as in Scores. edge: C_edge
    (N,) of one entry per particle (Scores.C_edge), idx (N,) int -> (N,) or None when off.
    """

    cos: np.ndarray
    stage_ms: dict[str, float] = field(default_factory=dict)
    misaligned: Callable[[np.ndarray], np.ndarray] | None = None
    reference: Reference | None = None
    edge: Callable[[np.ndarray], np.ndarray | None] | None = None


@runtime_checkable
class Likelihood(Protocol):
    """Scores N 6D pose hypotheses (egocentric R (N,3,3), t (N,3) metres) of one frame."""

    def score(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> Scores: ...


@runtime_checkable
class SingleFrameEstimator(Protocol):
    """Gives a pose from one frame alone (for MCL + E2E), or None if it cannot."""

    def single_frame_estimate(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None: ...


@runtime_checkable
class CodebookLikelihood(Protocol):
    """What the Rao-Blackwellised filters need: similarities with a whole orientation codebook.

    ``grid`` is the RotationGrid of allocentric codebook orientations (K entries).
    ``depth_weight`` (RGB-D) returns a per-particle factor (N,) in [0, 1] for the codebook
    entries ``idx`` (N,) placed at translations t (N,3), or None without depth.
    """

    grid: object

    def codebook_scores(self, frame: Frame, t: np.ndarray) -> CodebookScores: ...

    def depth_weight(self, frame: Frame, idx: np.ndarray, t: np.ndarray) -> np.ndarray | None: ...


@dataclass
class TrackResult:
    """The filter's output for one frame.

    R (3,3), t (3,) metres: the pose estimate (object to camera), None before the first
    detection. alpha: reinvigoration rate used for this frame's resampling (nan if none).
    sum_L, sum_C: sums of the likelihoods over the particles (nan when not computed).
    ess: effective sample size of the normalised weights (nan if not weighed).
    stage_ms: milliseconds per stage. ok: an estimate exists. weighed: this frame was scored.
    region: the search region's window (x, y, w, h) pixels searched on a frame without a
    detection (None: the frame had a detection, or nothing to search from).
    """

    R: np.ndarray | None
    t: np.ndarray | None
    alpha: float
    sum_L: float
    sum_C: float
    ess: float
    stage_ms: dict[str, float]
    ok: bool
    weighed: bool = False
    region: Box | None = None
