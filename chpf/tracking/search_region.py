"""Detector-free tracking: where phi_cand searches in a frame without a detection box.

Once a filter is initialised (by its first detection box), a frame without a box gets a search
region from the current estimate (``Region``, ``Frame.region``): its box is the model's
projected bounding box at the estimated pose (the bounding box of the projected
``chpf.tracking.model_outline`` points, the box a perfect detector would give), and its area,
where the candidates lie, is that box with each side times (1 + ``margin``), clipped to the
image. phi_cand reads the box as it reads a detection's (chpf.tracking.candidates).

The region widens with the filter's doubt. A weighed frame is *doubtful* when

- the method has a Counter-Hypothetical likelihood (CH-PF, CH-RBPF: ``sum_C`` is recorded):
  the set's doubt sum_C / (sum_C + sum_L) over its particles, of C and L as they are, is above
  ``alpha_doubt``. Not alpha itself: CH-PF's alpha measures the set against the best
  hypothesis at the region's own box (``chpf.reference: box``), where a set that lost the
  object finds its view as poor as the box's crop, so alpha stays low there;
- any other method: the mean unnormalised likelihood of its particles, sum_L / N, is below
  ``l_doubt``.

After ``patience`` doubtful frames in a row the scale grows by ``widen`` at every further
doubtful frame, until the window (the area times the scale, clipped) covers the whole image;
every frame that is not doubtful divides it by ``widen`` again, down to 1. Predict-only frames
change nothing. Without probes (``probes: 0``) phi_cand draws its candidates' centres in the
whole window and, once widened, its orientations uniformly (no look-up crop: the estimate's
place is in doubt).

A region that is not widened is *fitted* when a ``fitter`` (CH-PF's likelihood, with its
silhouette cue: chpf.tracking.silhouette) and ``fit_depths`` are given: the estimate is moved
along its ray to the factor of ``fit_depths`` (0.9-1.1 times its depth) at which its outline's
colour contrast is highest, and the box is that pose's projected box, marked ``Region.fitted``.
phi_cand reads it as it reads any region's box, and CH-PF's box-scale C reads it as it reads a
detection's: without a detector nothing else measures the object's size, and the belief crept
farther away (median +2.6 % on the dev suite's unoccluded frames; -0.2 % fitted).

*The outline's doubt* (``outline_doubt``, a share s, with a fitter): the fit's best contrast
also says whether the estimate is on the object. A frame whose contrast falls below s (0.5)
times the median of the last fitted frames that looked like the object (``calm_outlines``) is
*off the object*: it counts as doubtful (the window widens; checked on widened frames too), it
is not remembered (a lost set's outline does not become the yardstick), and the depth that
sizes the probes stays that of the last frame on the object. After a forced jump the set's
doubt stayed near ``alpha_doubt`` (0.45-0.65) while its outline's contrast fell from 0.6 to
0.04-0.2; the window closed again, the remembered contrast sank to the lost set's within 20
frames, and the probes, sized at the lost set's depth (half the true one), could not land on
the object. On forced-loss runs the ratio of the contrast to that median was below 0.5 on 95 %
of the frames more than 0.3 diameters off and on 2 % of the tracked ones (below 0.7, the
probes' bar: 97 % and 19 %; docs/own-recording.md).

With ``probes`` > 0:

- a widened frame is scanned over the whole image with square probe boxes
  (``SearchRegion.probe``): a grid (shifted at random each frame) whose sides lie within
  ``probe_sizes`` of the object's side at the depth of the last frame that was not widened
  (with ``outline_doubt``: of the last one that looked like the object),
  plus the best probes of the previous widened frame and jittered copies of them, then a finer
  pass of jittered copies of the best; every probe lies inside the image. Each is scored by
  ``probe_score`` (chpf.tracking.probe_scores: the log-odds log10(L^3 / C) of CH-PF's rule,
  1 - C, or the best cosine). Both networks' scores peak on the object only within about 0.1
  of its box side and 15 % of its size, so a probe must land almost on it;
- *the scene's colours* (``colour_weight``, in decades per unit): each clear fitted frame (see
  the yardstick below) teaches a ``ColourModel`` (chpf.tracking.colour_model) the object's
  colours inside its fitted outline and the background's outside, and every probe's score
  gains ``colour_weight`` times its box's colour contrast under that model. The networks were
  trained on renders: in a dark scene or at a grazing view they see the object about as weakly
  as a patch of background, and the scene's own colours still tell it apart;
- a calm frame scores ``calm_probes`` boxes over the image (``SearchRegion.remember``) and
  remembers the best places more than ``DECOY_AWAY`` sides from the estimate with their
  scores: *decoys*, what looks like the object while it is tracked elsewhere (a distractor, a
  patch of background). Under occlusion the object is hidden and such a place outscores the
  estimate's box; after a jump the object appears where nothing scored as well before;
- a probe's *gain* is its score less the best of the estimate's own box (and a few jittered
  copies of it) and of the decoys around it;
- *the outline check* (``probe_outline``): both networks score a refined probe on textured
  background or a distractor about as well as the object (in a heavily occluded dev scene a
  patch of floor scored 1.4 decades while the object was hidden, about 2 more than the same
  box in the last calm frame, whose texture had moved by a few pixels). A whole object also
  shows its outline: a probe's gain stands only when its outline contrast
  (chpf.tracking.silhouette; the best over its 3 best codebook orientations at 0.9, 1 and 1.1
  times its depth, and for the best probe of a pass also in its box moved by ``OUTLINE_SHIFT``)
  reaches ``probe_outline`` times the median of the *yardstick*, else it is lowered to the
  margin. The yardstick is the object as a probe saw it while tracked: on each of the last 20
  fitted frames that showed it at least as clearly as usual (``clearly_visible``: a slow
  occluder otherwise sank the bar), the same contrast in the object's square box around the
  fitted estimate (until one is measured, the fitted frames' own best contrast). Like for
  like: the outline is sharp in orientation (4-5 degrees off, the contrast fell from 0.82 to
  about 0.5), a probe's codebook orientations lie several degrees off, and against the
  estimate's refined contrast probes on the object failed the check for 20 frames. A probe
  that passes moves to the box where its outline fitted best, and the search goes on from
  there. With colours (``colour_weight`` > 0) a probe whose outline falls short passes all
  the same when its box's colour contrast reaches ``probe_outline`` times the median of the
  estimate's box's on the same clear fitted frames (``colour_yardstick``): on a grazing view
  the codebook's orientations missed the outline of the object for frames on end. A method
  without a silhouette (PoseRBPF, CH-RBPF: no fitted frame) has no such yardstick and does
  not probe while the check is on (``probe_outline: 0`` probes without it).

The probe with the highest gain takes over when that gain exceeds ``probe_margin``: it becomes
the region's box, so phi_cand draws around it, at its depth, with orientations that match its
crop, and the frame counts as doubtful whatever its alpha (``elsewhere``: the window stays open
while the filter has not moved there). Otherwise phi_cand draws around the estimate as on a
calm frame (``Region.scale`` 1; the window is still recorded as searched). A calm frame whose
own scan finds such a gain counts as doubtful too (CH-PF can settle on a wrong place with a low
alpha), so the window widens after ``patience`` frames.

The Rao-Blackwellised filters (PoseRBPF, CH-RBPF) draw at least ``poserbpf.search_fraction``
of their particles from phi_cand where a probe took over (``Region.probed``,
chpf.tracking.rbpf); without probes PoseRBPF draws only on its threshold reset. Unchecked
probes cost both filters AUC under heavy occlusion on the dev suite. Checked, they let CH-PF
re-acquire a jumped object in 29 of 36 runs (1 of 12 without probes) and keep 95 % of its
every-frame AUC on the bench with the first box only; under heavy occlusion they still cost
it on the dev suite (docs/own-recording.md). So CH-PF probes by default and the others do not.

``box_source`` (the ``search`` section of the tracking config) picks the box of each frame:
``auto`` the detection when the frame has one, else the search region unless a detector is
running (a box came after the first one: a frame it misses is predict-only, as the object is
most likely hidden; searching there cost every method 5-10 points under occlusion on the
bench); ``detections`` the
detection only (a frame without one is predict-only: no search region); ``estimate`` the
search region on every frame after the first detection (later detections are ignored).
"""

from __future__ import annotations

import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np

from chpf.config_schema import Invalid, Section, setting
from chpf.geometry import project_points
from chpf.tracking.colour_model import ColourModel
from chpf.tracking.model_outline import project_outline
from chpf.tracking.probe_scores import Probed, ProbeScoreName, probe_poses, probe_scores
from chpf.tracking.types import Box, Frame, Region, TrackResult

BoxSourceName = Literal["auto", "detections", "estimate"]
BOX_SOURCES: tuple[str, ...] = typing.get_args(BoxSourceName)
"""Where a frame's box comes from (module docstring)."""
JITTER = 0.15
"""Probe refinement: centre offsets and size changes of a jittered box (``jittered``)."""
OWN_JITTER = 4
"""Jittered copies of the estimate's box scored with it (``SearchRegion._own_boxes``)."""
OUTLINE_CHECKS = 3
"""The most probes per pass whose outline is checked (``SearchRegion.outlined``)."""
OUTLINE_ENTRIES = 3
"""Codebook orientations (the best cosines) at which a probe's outline is scored."""
OUTLINE_DEPTHS = (0.9, 1.0, 1.1)
"""Factors of a probe's depth at which its outline is scored."""
OUTLINE_SHIFT = 0.1
"""The best checked probe's outline is also scored with its box moved by this share of its
side (a probe lies within about 0.1 of a side of the object, and a box's outline is sharp;
shifting every checked probe let distractors through too: docs/own-recording.md)."""
CALM_OUTLINES = 20
"""Fitted frames whose outline contrasts make the yardstick of ``probe_outline``."""
DECOY_AWAY = 1.5
"""A decoy (``SearchRegion.remember``) lies more than this many object sides from the
estimate (nearer, the scores see the object's own shoulders)."""


class Outlined(Protocol):
    """What fitting a region's box needs from a likelihood (BundleLikelihood has it)."""

    def outline_contrast(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """Outline contrast (N,) of poses R (N,3,3), t (N,3) metres; None without a cue."""


@dataclass
class SearchConfig(Section):
    """The search region of frames without a detection (chpf.tracking.search_region):
    box_source (BOX_SOURCES); margin, the estimate's box side x (1 + margin); widen, the
    window's scale factor per doubtful frame; patience, doubtful frames in a row before it
    widens; alpha_doubt, CH-PF's / CH-RBPF's doubt above which a frame is doubtful; l_doubt,
    the mean L of the particles below which a frame of another method is doubtful; probes,
    the most grid boxes scored per widened frame over the whole image (0: no probes, phi_cand
    draws in the whole window); probe_sizes, their sides range from 1 / probe_sizes to
    probe_sizes times the object's side at the last calm depth (log-uniform); probe_score, how a
    probe is scored (chpf.tracking.probe_scores.PROBE_SCORES); probe_margin, how much a probe
    must score above the estimate's own box and above what was remembered at its place to take
    over (``SearchRegion.probe``); calm_probes, the probes scored per calm frame to remember
    the places elsewhere that look like the object (decoys; 0: none remembered); probe_outline,
    the share of the tracked object's outline contrast (as a probe saw it) a probe's must
    reach to take over (``SearchRegion.outlined``; 0: not checked, and every method probes);
    fit_depths,
    the factors of the estimate's depth among which a calm region's box is fitted to the
    outline's colour contrast (``SearchRegion.fitted``; empty: not fitted); outline_doubt, the
    share of the object's outline contrast below which a fitted estimate is off the object:
    it counts as doubtful, is not remembered and does not size the probes (module docstring;
    None: off); colour_weight, decades added to a probe's score per unit of its box's colour
    contrast under the colours learned while the object was tracked
    (chpf.tracking.colour_model; 0: off)."""

    box_source: BoxSourceName = "auto"
    margin: float = setting(0.2, ge=0.0)
    widen: float = setting(1.5, gt=1.0)
    patience: int = setting(3, ge=1)
    alpha_doubt: float = setting(0.6, ge=0.0, le=1.0)
    l_doubt: float = setting(0.55, ge=0.0, le=1.0)
    probes: int = setting(64, ge=0)
    probe_sizes: float = setting(1.2, ge=1.0)
    probe_score: ProbeScoreName = "odds"
    probe_margin: float = setting(0.5, ge=0.0)
    calm_probes: int = setting(16, ge=0)
    probe_outline: float = setting(0.7, ge=0.0, le=1.0)
    fit_depths: tuple[float, ...] = (0.9, 0.95, 1.0, 1.05, 1.1)
    outline_doubt: float | None = setting(0.5, gt=0.0, le=1.0)
    colour_weight: float = setting(6.0, ge=0.0)

    def check(self) -> None:
        if any(not f > 0 for f in self.fit_depths):
            raise Invalid("fit_depths", f"must be > 0, got {list(self.fit_depths)}")


def projected_box(points: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray) -> Box | None:
    """The bounding box (x, y, w, h) pixels of ``points`` (M,3) metres, object frame, under the
    pose R (3,3), t (3,) metres with intrinsics K (3,3); None when a point is not in front of
    the camera (z <= 1 mm) or the box is empty."""
    cam = points @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    if cam.shape[0] == 0 or np.min(cam[:, 2]) <= 1e-3:
        return None
    uv = project_points(cam, K)
    u, v = uv[:, 0], uv[:, 1]
    x0, y0 = float(u.min()), float(v.min())
    w, h = float(u.max()) - x0, float(v.max()) - y0
    if not (w > 0 and h > 0 and math.isfinite(w + h)):
        return None
    return (x0, y0, w, h)


def set_doubt(result: TrackResult) -> float:
    """The CH filters' doubt of a weighed frame, sum_C / (sum_C + sum_L) over the particles with
    C and L as they are (1 when both are 0; nan without C): what widens the region."""
    if not math.isfinite(result.sum_C):
        return math.nan
    total = result.sum_C + (result.sum_L if math.isfinite(result.sum_L) else 0.0)
    return 1.0 if total <= 0.0 else result.sum_C / total


def scaled_box(box: Box, scale: float) -> Box:
    """``box`` with its width and height times ``scale``, about its centre."""
    cx, cy = box[0] + 0.5 * box[2], box[1] + 0.5 * box[3]
    w, h = box[2] * scale, box[3] * scale
    return (cx - 0.5 * w, cy - 0.5 * h, w, h)


def full_scale(box: Box, width: int, height: int) -> float:
    """The least scale at which ``scaled_box(box, scale)`` covers the width x height image."""
    cx, cy = box[0] + 0.5 * box[2], box[1] + 0.5 * box[3]
    sx = 2.0 * max(cx, width - cx) / box[2]
    sy = 2.0 * max(cy, height - cy) / box[3]
    return max(sx, sy, 1.0)


def jittered(boxes: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` copies of each box (M,4) (x, y, w, h) pixels (box-major), each centre moved by up
    to ``JITTER`` of its box's width and height, each size times a log-uniform factor within
    1 +- ``JITTER`` (C's basin around the object is about that wide)."""
    boxes = np.repeat(np.asarray(boxes, dtype=np.float64).reshape(-1, 4), n, axis=0)
    m = boxes.shape[0]
    cx = boxes[:, 0] + 0.5 * boxes[:, 2] + JITTER * boxes[:, 2] * rng.uniform(-1.0, 1.0, m)
    cy = boxes[:, 1] + 0.5 * boxes[:, 3] + JITTER * boxes[:, 3] * rng.uniform(-1.0, 1.0, m)
    size = np.exp(rng.uniform(-1.0, 1.0, m) * math.log(1.0 + JITTER))
    w, h = boxes[:, 2] * size, boxes[:, 3] * size
    return np.stack([cx - w / 2, cy - h / 2, w, h], axis=1)


def inside(boxes: np.ndarray, width: int, height: int) -> np.ndarray:
    """Boxes (M,4) (x, y, w, h) pixels moved into the width x height image where they fit (a
    crop reaching past the border is padded, and the classifier takes some padded crops for
    the object)."""
    boxes = np.array(boxes, dtype=np.float64)
    boxes[:, 0] = np.clip(boxes[:, 0], 0.0, np.maximum(width - boxes[:, 2], 0.0))
    boxes[:, 1] = np.clip(boxes[:, 1], 0.0, np.maximum(height - boxes[:, 3], 0.0))
    return boxes


def clip_box(box: Box, width: int, height: int) -> Box | None:
    """``box`` clipped to the width x height image; None when nothing of it is inside."""
    x0, y0 = max(box[0], 0.0), max(box[1], 0.0)
    x1, y1 = min(box[0] + box[2], float(width)), min(box[1] + box[3], float(height))
    if x1 <= x0 or y1 <= y0:
        return None
    return (x0, y0, x1 - x0, y1 - y0)


class SearchRegion:
    """One tracked object's search region (module docstring).

    config: the ``search`` section; points: (M,3) metres, object frame, the model points whose
    projection bounds the object (a callable giving them: computed on first use); prober: what
    scores the probes of a widened window (None: no probes, phi_cand draws in the whole
    window); fitter: what fits a calm region's box to the image (None: not fitted). State:
    ``scale`` (>= 1), ``streak`` (doubtful weighed frames in a row).
    """

    def __init__(
        self,
        config: SearchConfig,
        points: np.ndarray | Callable[[], np.ndarray],
        prober: Probed | None = None,
        fitter: Outlined | None = None,
    ) -> None:
        self.config = config
        self._points = points
        self.prober = prober
        self.fitter = fitter
        self.colours = ColourModel()
        self.reset()

    def reset(self) -> None:
        """Not widened, no doubt (start of a sequence)."""
        self.scale = 1.0
        self.streak = 0
        self._full = math.inf  # the scale that covered the image at the last region
        self._box: Box | None = None  # the last region's box
        self.detector_running = False  # a box came after the first (``auto``)
        self._kept = np.zeros((0, 4))  # the best probes (M,4) of the last probed frame
        self._z = 1.0  # metres: the depth that sizes the probes (the estimate's at the last calm
        # frame; with outline_doubt, the fitted one at the last frame on the object)
        self.elsewhere = False  # the last probes found a better place than the estimate's
        self.decoys = np.zeros((0, 4))  # boxes (M,4) elsewhere that looked like the object ...
        self.decoy_scores = np.zeros(0)  # ... and their scores (M,) at the last calm frame
        self.calm_outlines: list[float] = []  # the best contrast of the last fitted frames
        self.probe_yardstick: list[float] = []  # a probe's contrast at the estimate's box on
        # the last clear fitted frames (``_remember_probe_outline``)
        self.off_object = False  # the estimate's outline did not look like the object's
        self.colours.reset()
        self.colour_yardstick: list[float] = []  # the estimate's box's colour contrast on the
        # last clear fitted frames (``teach_colours``)

    @property
    def points(self) -> np.ndarray:
        if callable(self._points):
            self._points = np.asarray(self._points(), dtype=np.float64)
        return self._points

    def region(
        self, R: np.ndarray, t: np.ndarray, K: np.ndarray, width: int, height: int
    ) -> Region | None:
        """The search region around the estimate R (3,3), t (3,) metres in a width x height
        image with intrinsics K (3,3), without probes: phi_cand's area is the whole window,
        and a widened one gives no look-up crop (``Region.cue``). Its window is the whole image
        when the
        estimate's box lies outside the image, or when the estimate is not in front of the
        camera (then the box is the last region's; None when there is none)."""
        whole = (0.0, 0.0, float(width), float(height))
        box = projected_box(self.points, R, t, K)
        if box is None:
            if self._box is None:
                return None
            return Region(self._box, whole, whole, math.inf, cue=False)
        self._box = box
        base = scaled_box(box, 1.0 + self.config.margin)
        self._full = full_scale(base, width, height)
        scale = min(self.scale, self._full)
        window = clip_box(scaled_box(base, scale), width, height)
        if window is None:
            return Region(box, whole, whole, math.inf, cue=False)
        return Region(box, window, window, scale, cue=scale <= 1.0)

    def probe_boxes(self, window: Box, side: float, rng: np.random.Generator, n: int) -> np.ndarray:
        """At most ``n`` square probes (M,4) (x, y, w, h) pixels: a grid over ``window`` whose
        step spreads ``n`` over its area, shifted at random by up to one step, each of side
        ``side`` pixels times a log-uniform factor in [1 / probe_sizes, probe_sizes]."""
        step = max(math.sqrt(window[2] * window[3] / max(n, 1)), 1.0)
        nx, ny = max(int(window[2] / step), 1), max(int(window[3] / step), 1)
        gx, gy = np.meshgrid(np.arange(nx), np.arange(ny))
        cx = window[0] + (gx.ravel() + rng.random()) * window[2] / nx
        cy = window[1] + (gy.ravel() + rng.random()) * window[3] / ny
        sizes = side * np.exp(
            rng.uniform(-1.0, 1.0, cx.shape[0]) * math.log(self.config.probe_sizes)
        )
        return np.stack([cx - sizes / 2, cy - sizes / 2, sizes, sizes], axis=1)

    def _side_at(self, frame: Frame, z: float) -> float:
        """The object's side in pixels at depth z metres: fx * box_extent / z."""
        assert self.prober is not None
        return float(frame.K[0, 0]) * self.prober.box_extent / z

    def probe_scores(self, frame: Frame, boxes: np.ndarray) -> np.ndarray:
        """Scores (M,) of probe boxes (M,4) (x, y, w, h) pixels by ``probe_score``, plus
        ``colour_weight`` times their colour contrast once colours are learned
        (``teach_colours``)."""
        assert self.prober is not None
        scores = probe_scores(self.prober, frame, boxes, self.config.probe_score)
        weight = self.config.colour_weight
        if weight > 0.0 and self.colours.ready:
            scores = scores + weight * self.colours.box_contrast(frame.rgb, boxes)
        return scores

    def teach_colours(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> None:
        """Learn the object's and the background's colours from ``frame`` with the object at
        R (3,3), t (3,) metres (a fitted pose that shows it clearly; chpf.tracking.colour_model),
        then keep its square box's colour contrast among the last ``CALM_OUTLINES`` (the
        ``colour_yardstick``: the object as a probe's colours see it)."""
        if self.config.colour_weight <= 0.0:
            return
        uv = project_outline(self.points, R[None], np.asarray(t)[None], frame.K, 1e-3)[0]
        self.colours.teach(frame.rgb, uv)
        own_box, _ = self._own_box(frame, t)
        contrast = float(self.colours.box_contrast(frame.rgb, own_box)[0])
        self.colour_yardstick = [*self.colour_yardstick, contrast][-CALM_OUTLINES:]

    def _own_box(self, frame: Frame, t: np.ndarray) -> tuple[np.ndarray, float]:
        """The square box (1,4) of the object at the estimate t (3,) metres (``_side_at`` its
        depth, around its projection) and that side in pixels."""
        side = self._side_at(frame, max(float(t[2]), 1e-3))
        u, v = project_points(np.asarray(t, dtype=np.float64)[None], frame.K)[0]
        return np.array([[u + 0.5 - side / 2, v + 0.5 - side / 2, side, side]]), side

    @staticmethod
    def _own_boxes(
        own_box: np.ndarray, rng: np.random.Generator, width: int, height: int
    ) -> np.ndarray:
        """The estimate's box (1,4) and ``OWN_JITTER`` jittered copies, inside the image: the
        estimate's score is the best of them (a probe's is refined over frames; the
        estimate's box alone, a tenth of a side off, scores orders of magnitude lower)."""
        return inside(np.concatenate([own_box, jittered(own_box, OWN_JITTER, rng)]), width, height)

    def _scored(
        self, frame: Frame, boxes: np.ndarray, own_box: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """Probe boxes (M,4) scored in one pass with the estimate's own box (1,4) and its
        jittered copies (``_own_boxes``): their scores (M,), the estimate's score (the best of
        its boxes), their ``gains`` (M,) and the boxes (M,4) as ``gains`` moved them."""
        assert self.prober is not None
        height, width = frame.rgb.shape[:2]
        own = self._own_boxes(own_box, rng, width, height)
        both = self.probe_scores(frame, np.concatenate([own, boxes]))
        own_score, scores = float(both[: len(own)].max()), both[len(own) :]
        return scores, own_score, *self.gains(frame, boxes, scores, own_box, own_score)

    def gains(self, frame: Frame, boxes: np.ndarray, scores: np.ndarray, own_box: np.ndarray,
              own_score: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """How much each probe (M,4) with ``scores`` (M,) beats what is known at its place: its
        score less the estimate's own box's ``own_score`` and less the remembered score of
        any decoy whose centre lies within half its side of the probe's; -inf for a probe
        within half a side of the estimate's box (not elsewhere); at most ``probe_margin`` for
        a probe whose outline does not look like the object's. Returns the gains (M,) and the
        boxes (M,4) as ``outlined`` moved them."""
        centres = boxes[:, :2] + boxes[:, 2:] / 2
        own_c, own_side = own_box[0, :2] + own_box[0, 2:] / 2, float(own_box[0, 2])
        bar = np.full(len(boxes), float(own_score))
        for d, d_score in zip(self.decoys, self.decoy_scores, strict=True):
            near = np.hypot(*(centres - (d[:2] + d[2:] / 2)).T) < 0.5 * d[2]
            bar = np.where(near, np.maximum(bar, d_score), bar)
        gain = np.asarray(scores, dtype=np.float64) - bar
        gain = np.where(np.hypot(*(centres - own_c).T) > 0.5 * own_side, gain, -np.inf)
        return self.outlined(frame, boxes, gain)

    @property
    def verifies(self) -> bool:
        """Whether a probe's outline is checked (``probe_outline`` > 0): then a method
        without a silhouette (no ``calm_outlines`` after a fitted frame) does not probe."""
        return self.config.probe_outline > 0.0

    def outlined(
        self, frame: Frame, boxes: np.ndarray, gain: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``gain`` (M,) of probes (M,4) with each of the ``OUTLINE_CHECKS`` highest above
        ``probe_margin`` kept only when its ``outline_contrast`` reaches ``probe_outline``
        times the median of the yardstick (``probe_yardstick``: the object as a probe saw it
        while tracked; ``calm_outlines`` until one is measured), else lowered to the margin;
        the others above the margin are lowered to it. Both networks score a refined probe on
        textured background or a distractor about as well as the object; the outline tells a
        whole object from them. A probe whose outline falls short passes all the same when
        its box's colour contrast reaches ``probe_outline`` times the median of the
        ``colour_yardstick`` (the object's seen the same way while tracked; a codebook
        orientation a few degrees off misses a sharp outline). Returns the gains and the
        boxes (M,4), a probe that passed by its outline moved to the box where the outline
        fitted best (the search goes on from there)."""
        over = np.flatnonzero(gain > self.config.probe_margin)
        yardstick = self.probe_yardstick or self.calm_outlines
        if not self.verifies or over.size == 0 or not yardstick:
            return gain, boxes
        order = over[np.argsort(-gain[over])]
        bar = self.config.probe_outline * float(np.median(yardstick))
        gain, boxes = gain.copy(), boxes.copy()
        colour_bar = self.config.probe_outline * self.tracked_colour_contrast()
        for k, i in enumerate(order):
            if k < OUTLINE_CHECKS:
                contrast, fitted_box = self.outline_contrast(frame, boxes[i], k == 0)
                if contrast >= bar:
                    boxes[i] = fitted_box
                    continue
                if self.colours.box_contrast(frame.rgb, boxes[i])[0] >= colour_bar:
                    continue
            gain[i] = self.config.probe_margin
        return gain, boxes

    def tracked_colour_contrast(self) -> float:
        """The median colour contrast of the estimate's box on the last clear fitted frames
        (``teach_colours``); inf while colours are off, unlearned, or do not set the object
        apart (a median <= 0): then no probe passes by its colours."""
        if self.config.colour_weight <= 0.0 or not self.colour_yardstick:
            return math.inf
        median = float(np.median(self.colour_yardstick))
        return median if median > 0.0 else math.inf

    def outline_contrast(
        self, frame: Frame, box: np.ndarray, shifted: bool = False
    ) -> tuple[float, np.ndarray]:
        """The best outline contrast (chpf.tracking.silhouette) of the object in the probe
        ``box`` (4,) pixels: at the ``OUTLINE_ENTRIES`` codebook orientations that best match
        its crop, at ``OUTLINE_DEPTHS`` times its depth; ``shifted``: also in the box moved
        by ``OUTLINE_SHIFT`` of its side in u, v or both (9 boxes). Returns that contrast and
        the box (4,) where it was found."""
        assert self.prober is not None and self.fitter is not None
        boxes = np.array(box, dtype=np.float64)[None]
        if shifted:
            steps = OUTLINE_SHIFT * np.array([-1.0, 0.0, 1.0])
            du, dv = (g.ravel() for g in np.meshgrid(steps, steps))
            boxes = np.repeat(boxes, du.size, axis=0)
            boxes[:, 0] += du * boxes[:, 2]
            boxes[:, 1] += dv * boxes[:, 3]
        R, t = probe_poses(self.prober, frame, boxes, OUTLINE_ENTRIES)  # (M,k,3,3), (M,3)
        factors = np.asarray(OUTLINE_DEPTHS)
        ts = factors[:, None, None, None] * np.broadcast_to(t[:, None], (*R.shape[:2], 3))
        Rs = np.broadcast_to(R, (factors.size, *R.shape)).reshape(-1, 3, 3)
        a = self.fitter.outline_contrast(frame, Rs, ts.reshape(-1, 3))
        if a is None:
            return 0.0, boxes[0]
        per_box = np.asarray(a).reshape(factors.size, *R.shape[:2]).max(axis=(0, 2))  # (M,)
        k = int(np.argmax(per_box))
        return float(per_box[k]), boxes[k]

    def remember(self, frame: Frame, t: np.ndarray, rng: np.random.Generator) -> None:
        """A calm frame's scan: ``calm_probes`` boxes over the whole image at the estimate's side (t
        (3,) metres; with ``outline_doubt`` the side at the depth where the estimate last looked
        like the object), among them the decoys so far, the places found last time and a jittered
        copy of each, scored with the estimate's own box. A probe whose ``gains`` exceed
        ``probe_margin`` is a place that looks more like the object than the estimate and than
        anything remembered there: ``elsewhere`` (the frame counts as doubtful: the filter can
        settle on a wrong place with a low alpha) and kept for the next frame's probes. Of the
        others, the best ``calm_probes`` / 4 more than ``DECOY_AWAY`` sides from the estimate become
        the decoys, with their scores (places that look like the object while it is tracked
        elsewhere: a distractor, a patch of background)."""
        n = self.config.calm_probes
        if self.prober is None or n <= 0:
            self._kept = np.zeros((0, 4))
            self.elsewhere = False
            return
        m = max(n // 4, 1)
        height, width = frame.rgb.shape[:2]
        whole = (0.0, 0.0, float(width), float(height))
        own_box, side = self._own_box(frame, t)
        kept = np.concatenate([self.decoys[:m], self._kept[:m]])
        grid_side = self._side_at(frame, self._z)  # the probes' depth (``frame``)
        grid = self.probe_boxes(whole, grid_side, rng, max(n - 2 * len(kept), 1))
        boxes = inside(np.concatenate([kept, jittered(kept, 1, rng), grid]), width, height)
        scores, _, gain, boxes = self._scored(frame, boxes, own_box, rng)
        found = gain > self.config.probe_margin
        self.elsewhere = bool(found.any())
        self._kept = boxes[found][np.argsort(-gain[found])[:m]]
        centres = boxes[:, :2] + boxes[:, 2:] / 2
        away = np.hypot(*(centres - own_box[0, :2] - side / 2).T) > DECOY_AWAY * side
        away &= ~found
        order = np.argsort(-scores[away])[:m]
        self.decoys, self.decoy_scores = boxes[away][order], scores[away][order]

    def probe(
        self, frame: Frame, region: Region, t: np.ndarray, rng: np.random.Generator
    ) -> Region:
        """``region`` with its box moved to the best probe when that probe takes over, else the
        estimate's (not widened) region. Per frame at most 1.5 ``probes`` boxes in two passes: the
        best ``probes`` / 8 boxes of the previous probed frame and a jittered copy of each (the
        object moves little between frames: the search goes on where it left off) and
        ``probe_boxes`` for the rest of ``probes``, of the object's side at the depth of the last
        frame that was not widened (with ``outline_doubt``: that looked like the object; its depth
        changes little while it is lost, unlike the estimate's); then ``probes`` / 2 jittered copies
        (``jittered``) of the probe with the highest ``gains``. The estimate's own box (at the
        estimate t (3,) metres) is scored with the first pass. Probes rank by ``gains``: their score
        less the estimate box's and less the decoys' nearby (``remember``), so that a place that
        already looked like the object while it was tracked elsewhere (under occlusion the object is
        hidden and a distractor wins) does not take over; the best ``probes`` / 8 are kept. The best
        takes over (``elsewhere``) when its gain exceeds ``probe_margin``: phi_cand draws around it,
        at its depth, with orientations from its crop."""
        assert self.prober is not None
        n = self.config.probes
        height, width = frame.rgb.shape[:2]
        whole = (0.0, 0.0, float(width), float(height))
        own_box, _ = self._own_box(frame, t)
        kept = np.concatenate([self._kept, jittered(self._kept, 1, rng)])
        grid = self.probe_boxes(whole, self._side_at(frame, self._z), rng, n - len(kept))
        coarse = inside(np.concatenate([kept, grid]), width, height)
        _, own_score, coarse_gains, coarse = self._scored(frame, coarse, own_box, rng)
        best = coarse[int(np.argmax(coarse_gains))]
        fine = inside(jittered(best[None], max(n // 2, 1), rng), width, height)
        fine_scores = self.probe_scores(frame, fine)
        fine_gains, fine = self.gains(frame, fine, fine_scores, own_box, own_score)
        boxes = np.concatenate([coarse, fine])
        gain = np.concatenate([coarse_gains, fine_gains])
        order = np.argsort(-gain)
        self._kept = boxes[order[: max(n // 8, 1)]]
        self.elsewhere = bool(gain[order[0]] > self.config.probe_margin)
        if not self.elsewhere:  # phi_cand draws as on a calm frame; the record shows the scan
            near = clip_box(scaled_box(region.box, 1.0 + self.config.margin), width, height)
            return replace(region, area=near or whole, window=whole, scale=1.0, cue=True)
        box = tuple(float(v) for v in boxes[order[0]])
        area = clip_box(scaled_box(box, 1.0 + self.config.margin), width, height)
        return Region(box, area or whole, whole, region.scale, probed=True)

    def doubtful(self, result: TrackResult, n_particles: int) -> bool | None:
        """Whether a frame's result shows doubt (module docstring); None for a frame that was
        not weighed (predict-only)."""
        if not result.weighed:
            return None
        if math.isfinite(result.sum_C):
            return bool(set_doubt(result) > self.config.alpha_doubt)
        mean_l = result.sum_L / n_particles if math.isfinite(result.sum_L) else 0.0
        return bool(mean_l < self.config.l_doubt)

    def outline_fit(
        self, frame: Frame, estimate: tuple[np.ndarray, np.ndarray]
    ) -> tuple[float, np.ndarray] | None:
        """The estimate R (3,3), t (3,) metres moved along its ray to the factor of
        ``fit_depths`` whose outline's colour contrast is highest: that contrast and the
        moved t (3,); None when nothing fits (no silhouette, no factors)."""
        factors = np.asarray(self.config.fit_depths, dtype=np.float64)
        if self.fitter is None or factors.size == 0:
            return None
        R, t = estimate
        ts = factors[:, None] * np.asarray(t, dtype=np.float64)[None]
        a = self.fitter.outline_contrast(frame, np.repeat(R[None], factors.size, axis=0), ts)
        if a is None:
            return None
        k = int(np.argmax(a))
        return float(a[k]), ts[k]

    def fitted(
        self, region: Region | None, R: np.ndarray, fit: tuple[float, np.ndarray] | None,
        K: np.ndarray,
    ) -> Region | None:  # fmt: skip
        """``region`` with its box the model's projected box at the estimate's orientation R
        (3,3) and the fitted t of ``fit`` (``outline_fit``), marked ``fitted`` (module
        docstring); as it is without a fit or when the fitted pose does not project."""
        if region is None or fit is None:
            return region
        box = projected_box(self.points, R, fit[1], K)
        return region if box is None else replace(region, box=box, fitted=True)

    def _remember_outline(self, contrast: float) -> None:
        """Keep a fitted frame's best outline ``contrast`` among the last ``CALM_OUTLINES``."""
        self.calm_outlines = [*self.calm_outlines, contrast][-CALM_OUTLINES:]

    def _remember_probe_outline(self, frame: Frame, t: np.ndarray) -> None:
        """Keep, among the last ``CALM_OUTLINES``, the ``outline_contrast`` that a probe at the
        object's square box around the fitted estimate t (3,) metres reaches: at codebook
        orientations, not the estimate's refined one (the probes' yardstick, like for like)."""
        own_box, _ = self._own_box(frame, t)
        contrast, _ = self.outline_contrast(frame, own_box[0])
        self.probe_yardstick = [*self.probe_yardstick, contrast][-CALM_OUTLINES:]

    def clearly_visible(self, contrast: float) -> bool:
        """Whether a fitted frame's outline ``contrast`` reaches the median of the last fitted
        frames (this one included): the object at least as clear as usual, so the frame may
        feed the probes' yardstick. A slow occluder lowers the contrast without taking the
        estimate off the object (``looks_like_object``), and would sink the bar with it."""
        return bool(self.calm_outlines) and contrast >= float(np.median(self.calm_outlines))

    def looks_like_object(self, contrast: float) -> bool:
        """Whether an outline ``contrast`` reaches ``outline_doubt`` (when on) times the median
        best contrast of the last fitted frames that looked like the object (True while none
        is remembered, or when the check is off)."""
        share = self.config.outline_doubt
        if share is None or not self.calm_outlines:
            return True
        return contrast >= share * float(np.median(self.calm_outlines))

    def update(self, result: TrackResult, n_particles: int) -> None:
        """Widen or shrink after a frame (module docstring; a frame whose probes found a better
        place elsewhere, or whose estimate is off the object by its outline, counts as
        doubtful); N = ``n_particles``."""
        doubt = self.doubtful(result, n_particles)
        if doubt is None:
            return
        if not doubt and not self.elsewhere and not self.off_object:
            self.streak = 0
            self.scale = max(self.scale / self.config.widen, 1.0)
            return
        self.streak += 1
        if self.streak >= self.config.patience:
            self.scale = min(self.scale * self.config.widen, max(self._full, 1.0))

    def frame(
        self,
        frame: Frame,
        estimate: tuple[np.ndarray, np.ndarray] | None,
        rng: np.random.Generator,
    ) -> Frame:
        """The frame the filter steps, by ``box_source``: ``frame`` as it is (its box: the
        checked detection or None), or with the search region around ``estimate`` (the
        filter's (R, t); None before the first detection: the frame as it is) instead of its
        box, probed with ``rng`` when widened. ``auto`` searches only while no detector runs."""
        source = self.config.box_source
        detected = frame.box is not None
        self.detector_running |= detected and estimate is not None
        if source == "auto" and self.detector_running:
            return frame
        if estimate is None or source == "detections" or (source == "auto" and detected):
            return frame
        height, width = frame.rgb.shape[:2]
        region = self.region(estimate[0], estimate[1], frame.K, width, height)
        widened = region is not None and region.scale > 1.0
        check = self.config.outline_doubt is not None and self.fitter is not None
        fit = None
        if region is not None and (check or not widened):
            fit = self.outline_fit(frame, estimate)
        if check:
            self.off_object = fit is not None and not self.looks_like_object(fit[0])
        probing = self.prober is not None and self.config.probes > 0
        probing &= not self.verifies or bool(self.calm_outlines)
        if widened and probing:
            region = self.probe(frame, region, estimate[1], rng)
        else:
            if not check:
                self._z = max(float(estimate[1][2]), 1e-3)
            if not widened:
                region = self.fitted(region, estimate[0], fit, frame.K)
                if fit is not None and not self.off_object:
                    self._remember_outline(fit[0])
                    if probing and self.verifies and self.clearly_visible(fit[0]):
                        self._remember_probe_outline(frame, fit[1])
                        self.teach_colours(frame, estimate[0], fit[1])
                    if check:
                        self._z = max(float(fit[1][2]), 1e-3)
            if region is not None and probing:
                self.remember(frame, estimate[1], rng)
            else:
                self._kept = np.zeros((0, 4))
                self.elsewhere = False
        return replace(frame, box=None, region=region)
