"""Detector-free tracking: the search region around the estimate, its widening and shrinking
with the filter's doubt, phi_cand inside it, and ``Tracker.step(box=None)`` on the demo."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from chpf.errors import ConfigError
from chpf.geometry import RotationGrid
from chpf.track_cli import main
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.config import make_config
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.probe_scores import PROBE_SCORES, probe_scores
from chpf.tracking.runlog import read_log
from chpf.tracking.search_region import SearchConfig, SearchRegion, projected_box, set_doubt
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import CodebookScores, Frame, Region, TrackResult
from tests.helpers import DEMO_K, demo_box, demo_frames

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
W, H = 320, 240
CUBE = 0.05 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def _result(alpha: float = float("nan"), sum_L: float = 0.0, sum_C: float = float("nan"),
            weighed: bool = True) -> TrackResult:  # fmt: skip
    return TrackResult(np.eye(3), np.zeros(3), alpha, sum_L, sum_C, 10.0, {}, True, weighed)


DOUBT = _result(alpha=0.9, sum_L=10.0, sum_C=40.0)  # CH-PF: doubt 0.8, above alpha_doubt
CALM = _result(alpha=0.05, sum_L=40.0, sum_C=2.0)


def test_the_estimate_region_is_the_projected_model_box_enlarged_by_the_margin():
    search = SearchRegion(SearchConfig(margin=0.2), CUBE)
    t = np.array([0.1, -0.05, 1.0])
    region = search.region(np.eye(3), t, K, W, H)
    # corners at x 0.05..0.15, y -0.1..0, z 0.95..1.05: x / z spans 0.05 / 1.05..0.15 / 0.95
    x0, x1 = 300 * 0.05 / 1.05 + 159.5, 300 * 0.15 / 0.95 + 159.5
    y0, y1 = 300 * -0.10 / 0.95 + 119.5, 300 * 0.0 / 0.95 + 119.5
    np.testing.assert_allclose(region.box, (x0, y0, x1 - x0, y1 - y0))
    side_w, side_h = 1.2 * (x1 - x0), 1.2 * (y1 - y0)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    np.testing.assert_allclose(region.area, (cx - side_w / 2, cy - side_h / 2, side_w, side_h))
    assert region.scale == 1.0 and region.window == region.area
    # turned 45 degrees about the optical axis: the corners reach 0.05 sqrt(2) from the centre
    R = cv2.Rodrigues(np.array([0.0, 0.0, np.pi / 4]))[0]
    turned = search.region(R, t, K, W, H)
    r = 0.05 * math.sqrt(2)
    assert turned.box[2] == pytest.approx(300 * ((0.1 + r) / 0.95 - (0.1 - r) / 1.05), rel=1e-9)
    assert projected_box(CUBE, np.eye(3), np.array([0.0, 0.0, 0.02]), K) is None  # behind


def test_doubt_widens_the_region_after_patience_up_to_the_whole_image_then_shrinks_back():
    cfg = SearchConfig(margin=0.0, widen=2.0, patience=3, alpha_doubt=0.5)
    search = SearchRegion(cfg, CUBE)
    R, t = np.eye(3), np.array([0.0, 0.0, 1.0])  # a 32 px box at the image centre
    base = search.region(R, t, K, W, H).window
    areas = []
    for _ in range(9):
        search.update(DOUBT, 50)
        areas.append(search.region(R, t, K, W, H).window)
    widths = [a[2] for a in areas]
    # two doubtful frames change nothing; from the third on each one doubles the side
    assert widths[:2] == [pytest.approx(base[2])] * 2
    assert widths[2:5] == pytest.approx([2 * base[2], 4 * base[2], 8 * base[2]])
    assert areas[-1] == (0.0, 0.0, float(W), float(H))  # capped at the whole image
    assert areas[-2] == areas[-1]
    # calm frames halve it again, one step per frame, down to the estimate's box
    shrunk = []
    for _ in range(6):
        search.update(CALM, 50)
        shrunk.append(search.region(R, t, K, W, H))
    cx = base[0] + base[2] / 2  # 159.5: the scale that first covers the image is set by x
    full = 2 * max(cx, W - cx) / base[2]
    expected = [max(full / 2**k, 1.0) for k in range(1, 7)]  # 5.1, 2.5, 1.3, 1, 1, 1
    assert [r.scale for r in shrunk] == pytest.approx(expected)
    assert [r.window[2] for r in shrunk[2:]] == pytest.approx(
        [expected[2] * base[2]] + [base[2]] * 3
    )
    assert shrunk[-1].scale == 1.0 and shrunk[-1].window == base
    # without probes phi_cand draws in the whole window, and once widened without a look-up
    assert all(r.area == r.window for r in shrunk)
    assert [r.cue for r in shrunk] == [False] * 3 + [True] * 3
    # a calm frame in the middle of a doubtful run starts the patience again
    for _ in range(2):
        search.update(DOUBT, 50)
    search.update(CALM, 50)
    search.update(DOUBT, 50)
    search.update(DOUBT, 50)
    assert search.scale == 1.0


def test_doubt_of_the_ch_filters_is_their_sums_of_c_and_l_not_alpha():
    """CH-PF's alpha measures the set against the region's own box (chpf.reference: box), so a
    set that lost the object can have alpha 0: the widening reads sum_C / (sum_C + sum_L)."""
    search = SearchRegion(SearchConfig(patience=1, widen=2.0, alpha_doubt=0.6), CUBE)
    search.update(_result(alpha=0.95, sum_L=30.0, sum_C=15.0), 50)  # doubt 0.33: calm
    assert search.scale == 1.0
    search.update(_result(alpha=0.0, sum_L=10.0, sum_C=30.0), 50)  # doubt 0.75: doubtful
    assert search.scale == 2.0
    search.update(_result(alpha=0.0, sum_L=0.0, sum_C=0.0), 50)  # no evidence either way
    assert search.scale == 4.0
    assert set_doubt(_result(sum_L=10.0, sum_C=30.0)) == pytest.approx(0.75)
    assert set_doubt(_result(sum_L=0.0, sum_C=0.0)) == 1.0
    assert math.isnan(set_doubt(_result(alpha=0.5, sum_L=30.0)))  # no C: no doubt of this kind


def test_doubt_of_methods_without_c_is_the_mean_likelihood_and_predict_only_frames_count_not():
    search = SearchRegion(SearchConfig(patience=1, widen=2.0, l_doubt=0.5), CUBE)
    search.update(_result(alpha=0.0, sum_L=0.6 * 50), 50)  # mean L 0.6: calm
    assert search.scale == 1.0
    search.update(_result(alpha=0.0, sum_L=0.3 * 50), 50)  # mean L 0.3: doubtful
    assert search.scale == 2.0
    search.update(_result(alpha=1.0, sum_L=0.3 * 50, weighed=False), 50)
    assert search.scale == 2.0 and search.streak == 1
    search.reset()
    assert search.scale == 1.0 and search.streak == 0


def test_box_source_picks_the_detection_or_the_region():
    est = (np.eye(3), np.array([0.0, 0.0, 1.0]))
    det = (10.0, 20.0, 30.0, 40.0)
    rgb = np.zeros((H, W, 3), np.uint8)

    def inputs(source, detection, estimate=est):
        search = SearchRegion(SearchConfig(box_source=source), CUBE)
        frame = search.frame(Frame(rgb, None, K, detection), estimate, np.random.default_rng(0))
        return frame.box, frame.region

    assert inputs("auto", det) == (det, None)
    box, region = inputs("auto", None)
    assert box is None and isinstance(region, Region)
    assert inputs("detections", None) == (None, None)
    box, region = inputs("estimate", det)
    assert box is None and region is not None  # detections ignored once tracking
    assert inputs("estimate", det, None) == (det, None)  # the first box starts it
    with pytest.raises(ConfigError, match="box_source"):
        make_config(None, ["search.box_source=sometimes"])


def test_auto_searches_only_while_no_detector_runs():
    """auto: with the first box only, a frame without one is searched; once a box has come
    after the first (a detector runs), a frame it misses is predict-only (no box, no region)."""
    rgb = np.zeros((H, W, 3), np.uint8)
    est, det = (np.eye(3), np.array([0.0, 0.0, 1.0])), (10.0, 20.0, 30.0, 40.0)
    search = SearchRegion(SearchConfig(box_source="auto"), CUBE)
    rng = np.random.default_rng(0)
    assert search.frame(Frame(rgb, None, K, det), None, rng).box == det  # the first box
    assert search.frame(Frame(rgb, None, K, None), est, rng).region is not None
    assert search.frame(Frame(rgb, None, K, det), est, rng).box == det  # a detector runs
    missed = search.frame(Frame(rgb, None, K, None), est, rng)
    assert missed.box is None and missed.region is None
    search.reset()
    assert search.frame(Frame(rgb, None, K, None), est, rng).region is not None


class DepthPeak:
    """A fitter whose outline contrast peaks at depth ``z`` metres (1 there, falling with
    |ln(z_hypothesis / z)|)."""

    def __init__(self, z):
        self.z = z

    def outline_contrast(self, frame, R, t):
        return 1.0 - np.abs(np.log(t[:, 2] / self.z))


def test_a_calm_region_takes_the_box_of_the_depth_whose_outline_fits_best():
    """The estimate at z 1.0 and an outline that fits best at 0.95: the region's box is the
    model's projected box at the factor 0.95 of fit_depths, marked fitted (a measurement that
    CH-PF's box scale reads); its window stays the estimate's. Not fitted: without a fitter,
    with no factors, or once widened."""
    rgb = np.zeros((H, W, 3), np.uint8)
    R, t = np.eye(3), np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(0)

    def region(cfg=None, fitter=DepthPeak(0.95)):  # noqa: B008
        search = SearchRegion(cfg or SearchConfig(box_source="estimate"), CUBE, None, fitter)
        return search, search.frame(Frame(rgb, None, K, None), (R, t), rng).region

    search, fitted = region()
    plain = search.region(R, t, K, W, H)
    assert fitted.fitted and not plain.fitted
    np.testing.assert_allclose(fitted.box, projected_box(CUBE, R, 0.95 * t, K))
    assert fitted.window == plain.window and fitted.area == plain.area
    assert not region(fitter=None)[1].fitted
    assert not region(SearchConfig(box_source="estimate", fit_depths=()))[1].fitted
    search, _ = region(SearchConfig(box_source="estimate", patience=1, widen=2.0))
    search.update(DOUBT, 50)
    assert not search.frame(Frame(rgb, None, K, None), (R, t), rng).region.fitted
    with pytest.raises(ConfigError, match="fit_depths"):
        make_config(None, ["search.fit_depths=[0.0, 1.0]"])


class Contrast:
    """A fitter whose outline contrast is ``value`` at every pose (set by the test)."""

    def __init__(self, value):
        self.value = value

    def outline_contrast(self, frame, R, t):
        return np.full(t.shape[0], self.value)


@pytest.mark.parametrize("outline_doubt", [0.5, None])
def test_an_estimate_whose_outline_is_unlike_the_objects_widens_the_window(outline_doubt):
    """Three calm frames on the object (contrast 0.8), then the estimate jumps to half its depth
    where the outline fits at 0.2, below ``outline_doubt`` (0.5) times 0.8, with a set that is
    not in doubt. With the check (the default) those frames are off the object: after
    ``patience`` of them the window widens, their contrast is not remembered and the depth
    that sizes the probes stays the object's; once the outline fits again (0.48: 0.6 of the
    object's, enough), the window shrinks. Without it the window never widens and the lost
    set becomes the yardstick."""
    assert SearchConfig().outline_doubt == 0.5
    cfg = SearchConfig(box_source="estimate", patience=2, widen=2.0, probes=0,
                       fit_depths=(1.0,), outline_doubt=outline_doubt)  # fmt: skip
    fitter = Contrast(0.8)
    search = SearchRegion(cfg, CUBE, None, fitter)
    frame, rng = Frame(np.zeros((H, W, 3), np.uint8), None, K), np.random.default_rng(0)
    R = np.eye(3)
    for _ in range(3):
        search.frame(frame, (R, np.array([0.0, 0.0, 1.0])), rng)
        search.update(CALM, 50)
    assert search.scale == 1.0 and search.calm_outlines == [0.8] * 3
    fitter.value = 0.2
    scales = []
    for _ in range(4):
        search.frame(frame, (R, np.array([0.0, 0.0, 0.5])), rng)
        search.update(CALM, 50)
        scales.append(search.scale)
    if outline_doubt:
        assert search.off_object and scales[:3] == [1.0, 2.0, 4.0] and scales[3] > 4.0
        assert search.calm_outlines == [0.8] * 3 and search._z == 1.0
        fitter.value = 0.48
        search.frame(frame, (R, np.array([0.0, 0.0, 0.5])), rng)
        search.update(CALM, 50)
        assert not search.off_object and search.scale == pytest.approx(scales[3] / 2)
    else:
        assert not search.off_object and scales == [1.0] * 4
        assert search.calm_outlines == [0.8] * 3 + [0.2] * 4 and search._z == 0.5


class PeakProber:
    """A likelihood whose probe score (the cosine kind) peaks at boxes centred on ``centre``
    with side ``side`` pixels: 1 at the peak, falling by one per ``width`` of the side off
    centre and per ``width`` in log size (the real networks' peak is about 0.1 side wide)."""

    box_extent = 0.1  # metres: a box of side s pixels stands for the object at z = 300 * 0.1 / s

    def __init__(self, centre, side, width=1.0):
        self.centre, self.side, self.width, self.calls = np.array(centre), side, width, 0

    def codebook_scores(self, frame, t):
        self.calls += 1
        uv = t[:, :2] / t[:, 2:] * K[0, 0] + K[:2, 2]
        side = K[0, 0] * self.box_extent / t[:, 2]
        off = np.linalg.norm(uv + 0.5 - self.centre, axis=1) / self.side
        cos = 1.0 - (off + np.abs(np.log(side / self.side))) / self.width
        return CodebookScores(cos=cos[:, None])


UNCHECKED = dict(
    patience=1, widen=2.0, probes=64, probe_score="cosine", probe_outline=0.0, probe_sizes=2.0
)
"""A search whose probes take over unchecked by the outline (the fakes have no silhouette)."""


def _widened(search, frame, est, rng):
    for _ in range(6):
        search.update(DOUBT, 50)
    return search.frame(frame, est, rng).region


def test_a_widened_window_is_probed_and_its_best_box_becomes_phi_cands():
    prober = PeakProber((250.0, 60.0), 40.0)  # the object: far from the estimate
    cfg = SearchConfig(**UNCHECKED, calm_probes=0)
    search = SearchRegion(cfg, CUBE, prober)
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # a 32 px box around (130, 135)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    rng = np.random.default_rng(0)
    narrow = search.frame(frame, est, rng).region
    assert prober.calls == 0 and narrow.box == search.region(*est, K, W, H).box  # no probes
    wide = _widened(search, frame, est, rng)
    assert wide.window == (0.0, 0.0, float(W), float(H)) and prober.calls == 2
    centre = np.array(wide.box[:2]) + np.array(wide.box[2:]) / 2
    assert np.linalg.norm(centre - (250.0, 60.0)) < 20.0  # the probes found it (one frame)
    assert 0.7 < wide.box[2] / 40.0 < 1.4
    side = np.array(wide.box[2:]) * 1.2
    np.testing.assert_allclose(wide.area, (*(centre - side / 2), *side))  # phi_cand's area
    boxes = search.probe_boxes(wide.window, 30.0, np.random.default_rng(1), 64)
    assert 48 <= len(boxes) <= 64 and boxes[:, 0].min() < 40 and boxes[:, 0].max() > 250
    assert np.all(boxes[:, 2] == boxes[:, 3]) and np.all(
        np.abs(np.log(boxes[:, 2] / 30)) <= np.log(2)
    )


def test_the_best_probes_carry_over_widened_frames_so_a_narrow_peak_is_found():
    # a peak 0.1 of the side wide: one frame's 96 probes rarely land in it; carried over and
    # refined from frame to frame they do. A calm frame without its own scan forgets them.
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))
    cfg = SearchConfig(**UNCHECKED, calm_probes=0)
    found = []
    for seed in range(5):
        search = SearchRegion(cfg, CUBE, PeakProber((250.0, 60.0), 40.0, width=0.1))
        rng = np.random.default_rng(seed)
        for _ in range(8):
            box = _widened(search, frame, est, rng).box
        found.append(np.hypot(box[0] + box[2] / 2 - 250.0, box[1] + box[3] / 2 - 60.0) < 6.0)
    assert sum(found) >= 4
    search.update(CALM, 50)
    search.scale = 1.0
    search.frame(frame, est, rng)
    assert search._kept.shape == (0, 4)


def test_the_window_stays_widened_while_a_probe_elsewhere_beats_the_estimates_box():
    # a calm alpha on a wrong place (CH-PF settles on background) does not shrink the window
    # while the probes find something better elsewhere; on the object it shrinks again
    cfg = SearchConfig(**UNCHECKED)
    search = SearchRegion(cfg, CUBE, PeakProber((250.0, 60.0), 40.0))
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    rng = np.random.default_rng(0)
    _widened(search, frame, (np.eye(3), np.array([-0.1, 0.05, 1.0])), rng)
    assert search.elsewhere
    search.update(DOUBT, 50)  # the scale, clamped to the whole image
    scale = search.scale
    search.update(CALM, 50)
    assert search.scale == scale and search.streak > 0
    on_it = np.array([90.0 * 0.75 / 300.0, -60.0 * 0.75 / 300.0, 0.75])  # its 40 px box at 250, 60
    search.frame(frame, (np.eye(3), on_it), rng)
    assert not search.elsewhere
    search.update(CALM, 50)
    assert search.scale == scale / 2.0 and search.streak == 0


class Peaks:
    """A likelihood whose probe score (the cosine kind) is ``floor`` (background) but near
    the peaks ``(centre, side, height)``: height less two per side off centre and one per unit
    of log size (the real scores' peaks are narrower still: about 0.1 side)."""

    box_extent = 0.1
    grid = RotationGrid(np.eye(3)[None])

    def __init__(self, peaks, floor=0.5):
        self.peaks, self.floor, self.calls = peaks, floor, 0

    def codebook_scores(self, frame, t):
        self.calls += 1
        uv = t[:, :2] / t[:, 2:] * K[0, 0] + K[:2, 2]
        side = K[0, 0] * self.box_extent / t[:, 2]
        cos = np.full(len(t), self.floor)
        for centre, s, height in self.peaks:
            off = np.linalg.norm(uv + 0.5 - np.array(centre), axis=1) / s
            cos = np.maximum(cos, height - 2.0 * off - np.abs(np.log(side / s)))
        return CodebookScores(cos=cos[:, None])


def test_a_place_that_looked_like_the_object_while_it_was_tracked_does_not_take_over():
    """Calm frames remember the places elsewhere that look like the object (a distractor);
    when the filter doubts (the object hidden), a probe there scores no better than
    remembered and phi_cand stays at the estimate's box; a new peak elsewhere (the object
    after a jump) beats the estimate's box and the remembered places and takes over."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # a 30 px box around (130, 135)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    cfg = SearchConfig(
        patience=1, widen=2.0, probes=64, probe_score="cosine", probe_outline=0.0, probe_sizes=1.5,
        probe_margin=0.2, calm_probes=64,
    )  # fmt: skip
    distractor = ((250.0, 60.0), 36.0, 1.4)
    search = SearchRegion(cfg, CUBE, Peaks([distractor]))
    rng = np.random.default_rng(0)
    for _ in range(12):  # calm frames
        region = search.frame(frame, est, rng).region
        assert region.scale == 1.0
    assert search.prober.calls == 12  # one pass of calm_probes per calm frame
    d = search.decoys[0]
    assert np.hypot(d[0] + d[2] / 2 - 250.0, d[1] + d[3] / 2 - 60.0) < 8.0
    assert search.decoy_scores[0] > 1.2
    own = search.region(*est, K, W, H)
    for _ in range(4):  # the object hidden: doubt, the window widens, the distractor waits
        wide = _widened(search, frame, est, rng)
        assert wide.window == (0.0, 0.0, float(W), float(H)) and not search.elsewhere
        assert wide.box == own.box and wide.area == own.area and wide.cue and wide.scale == 1
        assert not wide.probed  # the Rao-Blackwellised filters draw nothing there
    search.prober = Peaks([distractor, ((60.0, 60.0), 36.0, 1.5)])  # the object, elsewhere
    for _ in range(6):  # the probes carry over widened frames until they land on it
        wide = _widened(search, frame, est, rng)
        if search.elsewhere:
            break
    assert search.elsewhere and wide.probed
    assert np.hypot(wide.box[0] + wide.box[2] / 2 - 60.0, wide.box[1] + wide.box[3] / 2 - 60.0) < 12
    search.decoys, search.decoy_scores = np.zeros((0, 4)), np.zeros(0)  # nothing remembered:
    search.prober = Peaks([distractor])  # the distractor beats the estimate's box: it wins
    for _ in range(6):
        wide = _widened(search, frame, est, rng)
        if search.elsewhere:
            break
    assert search.elsewhere and abs(wide.box[0] + wide.box[2] / 2 - 250.0) < 8


def test_a_calm_frame_whose_scan_finds_a_better_place_elsewhere_widens_the_window():
    """CH-PF can settle on a wrong place with a calm alpha: a calm frame's scan that finds a
    place scoring above the estimate's box (and above anything remembered there) by the
    margin counts the frame as doubtful, so the window widens after ``patience`` frames and
    the probes take the place over."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # on background (the floor)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    cfg = SearchConfig(
        patience=2, widen=2.0, probes=64, probe_score="cosine", probe_outline=0.0, probe_sizes=1.5,
        probe_margin=0.2, calm_probes=64,
    )  # fmt: skip
    search = SearchRegion(cfg, CUBE, Peaks([((60.0, 60.0), 36.0, 1.5)]))
    rng = np.random.default_rng(0)
    scales = []
    for _ in range(12):
        region = search.frame(frame, est, rng).region
        search.update(CALM, 50)  # the filter's alpha is calm throughout
        scales.append(region.scale)
        if region.scale > 1.0 and search.elsewhere:
            break
    assert scales[0] == 1.0 and scales[-1] > 1.0  # widened without a doubtful alpha
    c = np.array(region.box[:2]) + np.array(region.box[2:]) / 2
    assert np.hypot(*(c - (60.0, 60.0))) < 12.0  # phi_cand draws at the place found
    quiet = SearchRegion(cfg, CUBE, Peaks([]))  # nothing better anywhere: calm stays calm
    for _ in range(6):
        assert quiet.frame(frame, est, rng).region.scale == 1.0
        quiet.update(CALM, 50)
        assert not quiet.elsewhere


class Outline:
    """A silhouette whose outline contrast is 0.9 for poses that project within 10 px of
    ``centre`` (the whole object there) and ``floor`` elsewhere (background, a distractor)."""

    def __init__(self, centre, floor=0.1):
        self.centre, self.floor, self.calls = np.array(centre), floor, 0

    def outline_contrast(self, frame, R, t):
        self.calls += 1
        uv = t[:, :2] / t[:, 2:] * K[0, 0] + K[:2, 2]
        return np.where(np.linalg.norm(uv + 0.5 - self.centre, axis=1) < 10.0, 0.9, self.floor)


def test_a_probe_takes_over_only_where_its_outline_looks_like_the_tracked_objects():
    """The networks score a distractor above the estimate's box and above anything remembered
    (nothing is, here): without the outline check it takes over; with it (``probe_outline``,
    the default) the outline there is far below the object's while it was tracked, so
    phi_cand stays at the estimate; the object elsewhere, whose outline fits, takes over."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # the estimate's box around (130, 135)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    distractor = ((250.0, 60.0), 36.0, 1.4)
    assert SearchConfig().probe_outline == 0.7 and SearchConfig().probes == 64

    def run(probe_outline, peaks, outline):
        cfg = SearchConfig(
            patience=1, widen=2.0, probe_score="cosine", probe_sizes=1.5, probe_margin=0.2,
            calm_probes=0, probe_outline=probe_outline,
        )  # fmt: skip
        search = SearchRegion(cfg, CUBE, Peaks(peaks), outline)
        rng = np.random.default_rng(0)
        search.frame(frame, est, rng)  # a calm, fitted frame: the object's outline, 0.9 at
        for _ in range(8):  # the estimate; the window widens and the probes search
            wide = _widened(search, frame, est, rng)
            if search.elsewhere:
                break
        return search, wide

    at_estimate = (130.0, 135.0)
    search, wide = run(0.0, [distractor], Outline(at_estimate))
    assert search.elsewhere and abs(wide.box[0] + wide.box[2] / 2 - 250.0) < 12
    search, wide = run(0.7, [distractor], Outline(at_estimate))
    assert search.calm_outlines == [0.9] and search.fitter.calls > 1  # probes were checked
    assert not search.elsewhere and not wide.probed and wide.scale == 1.0
    search, wide = run(0.7, [distractor], Outline(at_estimate, floor=0.9))
    assert search.elsewhere and wide.probed  # an outline as good as the object's: it is one


def test_the_best_checked_probe_is_also_scored_a_tenth_of_its_side_off():
    """A probe lies within about 0.1 of a side of the object and a box's outline is sharp: the
    best checked probe is also scored in its box moved by 0.1 of its side (9 boxes)."""
    search = SearchRegion(SearchConfig(), CUBE, Peaks([]), Outline((100.0, 100.0)))
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    box = np.array([62.0 - 0.5, 50.0 - 0.5, 100.0, 100.0])  # centred 12 px right of it
    assert search.outline_contrast(frame, box)[0] == pytest.approx(0.1)
    contrast, fitted = search.outline_contrast(frame, box, shifted=True)
    assert contrast == pytest.approx(0.9)
    assert fitted == pytest.approx(box - [10.0, 0.0, 0.0, 0.0])  # the box where it fitted


def test_a_probe_that_passes_moves_to_the_box_where_its_outline_fitted():
    """The best checked probe whose outline passes comes back moved to the shifted box where
    its outline fitted best (the search goes on from there); a probe below the bar keeps its
    box and is lowered to the margin; the boxes passed in are not changed."""
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    box = np.array([62.0 - 0.5, 50.0 - 0.5, 100.0, 100.0])  # centred 12 px right of it
    search = SearchRegion(SearchConfig(), CUBE, Peaks([]), Outline((100.0, 100.0)))
    search.calm_outlines = [0.9]
    boxes = np.stack([box, box + np.array([150.0, 0.0, 0.0, 0.0])])  # fits nowhere
    gain, moved = search.outlined(frame, boxes, np.array([2.0, 1.0]))
    assert gain[0] == 2.0 and gain[1] == search.config.probe_margin
    assert moved[0] == pytest.approx(box - [10.0, 0.0, 0.0, 0.0])
    assert moved[1] == pytest.approx(boxes[1]) and boxes[0] == pytest.approx(box)


class RefinedOutline:
    """A silhouette whose outline contrast is 0.9 at the identity orientation (the tracked
    estimate's refined one), 0.45 at any other (a codebook orientation seen off the optical
    axis: a few degrees off) and ``floor`` near ``distractor``."""

    def __init__(self, distractor, floor=0.1):
        self.distractor, self.floor = np.array(distractor), floor

    def outline_contrast(self, frame, R, t):
        uv = t[:, :2] / t[:, 2:] * K[0, 0] + K[:2, 2]
        refined = np.abs(R - np.eye(3)).max(axis=(1, 2)) < 1e-6
        a = np.where(refined, 0.9, 0.45)
        return np.where(np.linalg.norm(uv + 0.5 - self.distractor, axis=1) < 20.0, self.floor, a)


def test_the_probes_yardstick_is_a_probes_outline_at_the_tracked_estimate():
    """A probe's outline is scored at codebook orientations, the tracked estimate's at its
    refined one, which fits better (here 0.45 against 0.9). The calm frames measure the
    outline a probe at the estimate's box reaches, and the probes' bar is that share of it:
    a probe on the object after a jump takes over, one on a distractor does not. Against the
    estimate's own contrast (the yardstick emptied) the object's probe cannot pass."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # the estimate's box around (130, 135)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    distractor, jumped = ((250.0, 60.0), 36.0, 1.6), ((60.0, 60.0), 36.0, 1.5)
    cfg = SearchConfig(
        patience=1, widen=2.0, probe_score="cosine", probe_sizes=1.5, probe_margin=0.2,
        calm_probes=0,
    )  # fmt: skip

    def run(peaks, forget):
        search = SearchRegion(cfg, CUBE, Peaks([]), RefinedOutline(distractor[0]))
        rng = np.random.default_rng(0)
        for _ in range(3):  # calm, fitted frames on the object
            assert search.frame(frame, est, rng).region.scale == 1.0
        assert search.calm_outlines == [0.9] * 3 and search.probe_yardstick == [0.45] * 2
        if forget:
            search.probe_yardstick = []
        search.prober = Peaks(peaks)
        for _ in range(8):
            wide = _widened(search, frame, est, rng)
            if search.elsewhere:
                break
        return search, wide

    search, wide = run([distractor, jumped], forget=False)
    assert search.elsewhere and wide.probed
    assert np.hypot(wide.box[0] + wide.box[2] / 2 - 60.0, wide.box[1] + wide.box[3] / 2 - 60.0) < 18
    search, wide = run([distractor], forget=False)
    assert not search.elsewhere and not wide.probed
    search, wide = run([distractor, jumped], forget=True)
    assert not search.elsewhere and not wide.probed


def test_a_frame_dimmed_by_a_slow_occluder_does_not_lower_the_probes_yardstick():
    """A fitted frame whose outline is fainter than usual (an occluder sliding in) but still
    the object's is remembered as the object, but does not feed the probes' yardstick: the bar
    would sink with the occluder and let background through."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    cfg = SearchConfig(calm_probes=0)
    search = SearchRegion(cfg, CUBE, Peaks([]), RefinedOutline((0.0, 0.0)))
    rng = np.random.default_rng(0)
    for _ in range(3):
        search.frame(frame, est, rng)
    assert search.probe_yardstick == [0.45] * 2
    search.fitter = RefinedOutline((0.0, 0.0))
    search.fitter.outline_contrast = lambda f, R, t: 0.6 * np.ones(len(t))  # dimmed, same pose
    search.frame(frame, est, rng)
    assert search.calm_outlines[-1] == 0.6 and not search.off_object
    assert search.probe_yardstick == [0.45] * 2
    assert search.clearly_visible(0.9) and not search.clearly_visible(0.6)


def _red_square(cx: float, cy: float, side: int = 30) -> np.ndarray:
    """A frame: a red square of ``side`` pixels centred on (cx, cy) on teal and grey stripes."""
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[:] = (20, 120, 120)
    rgb[:, ::8] = (90, 90, 90)
    x, y = round(cx - side / 2), round(cy - side / 2)
    rgb[y : y + side, x : x + side] = (200, 30, 30)
    return rgb


@pytest.mark.parametrize("colour_weight", [0.0, 6.0])
def test_networks_blind_to_the_object_re_find_it_by_the_colours_learned_while_tracking(
    colour_weight,
):
    """Where the networks score the object no better than background (a dark scene, a
    grazing view), the colours learned on the clear fitted frames find it after a jump: its
    box's colour contrast lifts its probe over the estimate's box and the outline passes."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))  # the estimate's box around (130, 135)
    cfg = SearchConfig(
        patience=1, widen=2.0, probe_score="cosine", probe_sizes=1.5, probe_margin=0.2,
        calm_probes=0, colour_weight=colour_weight,
    )  # fmt: skip
    assert SearchConfig().colour_weight == 6.0
    search = SearchRegion(cfg, CUBE, Peaks([]), Outline((130.0, 135.0), floor=0.9))
    rng = np.random.default_rng(0)
    tracked = Frame(_red_square(130.0, 135.0), None, K)
    for _ in range(3):  # calm, fitted frames on the object: its colours are learned
        search.frame(tracked, est, rng)
    assert search.colours.ready == (colour_weight > 0)
    jumped = Frame(_red_square(250.0, 60.0), None, K)
    for _ in range(8):
        wide = _widened(search, jumped, est, rng)
        if search.elsewhere:
            break
    if colour_weight == 0.0:  # flat scores: nothing beats the estimate's box
        assert not search.elsewhere and not wide.probed
        return
    assert search.elsewhere and wide.probed
    centre = np.array(wide.box[:2]) + np.array(wide.box[2:]) / 2
    assert np.hypot(*(centre - (250.0, 60.0))) < 22  # on the 30 px object


@pytest.mark.parametrize("colour_weight", [0.0, 6.0])
def test_a_probe_whose_outline_misses_passes_where_its_colours_are_the_objects(colour_weight):
    """The outline check fails everywhere off the estimate (the probes' codebook orientations
    miss a grazing view's outline): a distractor that the networks prefer stays out, and the
    jumped object passes by its colours (its box's colour contrast reaches 0.7 of the
    estimate's box's while tracked), unless colours are off."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))
    cfg = SearchConfig(
        patience=1, widen=2.0, probe_score="cosine", probe_sizes=1.5, probe_margin=0.2,
        calm_probes=0, colour_weight=colour_weight,
    )  # fmt: skip
    distractor = ((60.0, 60.0), 36.0, 1.4)  # the networks' best place: on teal background
    search = SearchRegion(cfg, CUBE, Peaks([]), Outline((130.0, 135.0)))
    rng = np.random.default_rng(0)
    for _ in range(3):
        search.frame(Frame(_red_square(130.0, 135.0), None, K), est, rng)
    assert len(search.colour_yardstick) == (2 if colour_weight else 0)  # clear frames 2, 3
    search.prober = Peaks([distractor])
    jumped = Frame(_red_square(250.0, 60.0), None, K)
    for _ in range(8):
        wide = _widened(search, jumped, est, rng)
        if search.elsewhere:
            break
    if colour_weight == 0.0:
        assert not search.elsewhere and not wide.probed
        return
    assert search.elsewhere and wide.probed
    centre = np.array(wide.box[:2]) + np.array(wide.box[2:]) / 2
    assert np.hypot(*(centre - (250.0, 60.0))) < 22


def test_a_method_without_a_silhouette_does_not_probe_while_probes_are_checked():
    """PoseRBPF and CH-RBPF have no silhouette (no fitted frame, no yardstick): with the
    outline check on they search as with ``probes: 0`` (the whole window, no probe scored)."""
    est = (np.eye(3), np.array([-0.1, 0.05, 1.0]))
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    prober = Peaks([((250.0, 60.0), 36.0, 1.4)])
    search = SearchRegion(SearchConfig(patience=1, widen=2.0), CUBE, prober)
    rng = np.random.default_rng(0)
    search.frame(frame, est, rng)
    wide = _widened(search, frame, est, rng)
    assert prober.calls == 0 and not wide.probed and wide.scale > 1.0
    assert wide.area == wide.window  # phi_cand draws in the whole window


def test_probes_lie_inside_the_image():
    # a crop past the border is padded: the classifier took a padded one for the object
    prober = PeakProber((300.0, 10.0), 80.0)  # a peak at the corner: boxes would reach out
    cfg = SearchConfig(**UNCHECKED)
    search = SearchRegion(cfg, CUBE, prober)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K)
    box = _widened(
        search, frame, (np.eye(3), np.array([-0.1, 0.05, 1.0])), np.random.default_rng(0)
    ).box
    assert box[0] >= 0 and box[1] >= 0 and box[0] + box[2] <= W and box[1] + box[3] <= H


def test_probe_scores_of_the_shipped_networks_peak_on_the_object():
    # the demo's first frame: the object's box scores above 100 boxes of its size elsewhere,
    # by both scores
    from chpf.bundle import Bundle
    from chpf.tracking.bundle_likelihood import BundleLikelihood

    likelihood = BundleLikelihood(Bundle.load(shipped_bundle()))
    frame = Frame(_demo_rgb(1)[0], None, DEMO_K)
    x, y, w, h = demo_box(1)
    cx, cy, s = x + w / 2, y + h / 2, max(w, h)
    rng = np.random.default_rng(0)
    side = s * np.exp(rng.uniform(-1.0, 0.5, 300) * np.log(1.5))
    boxes = np.stack([rng.uniform(0, W - side), rng.uniform(0, H - side), side, side], axis=1)
    far = np.hypot(boxes[:, 0] + side / 2 - cx, boxes[:, 1] + side / 2 - cy) > s / 2
    boxes = np.concatenate([[[cx - s / 2, cy - s / 2, s, s]], boxes[far][:100]])
    for kind in PROBE_SCORES:
        assert np.argmax(probe_scores(likelihood, frame, boxes, kind)) == 0, kind


def test_phi_cand_draws_inside_the_region_with_the_depth_of_its_object_box():
    sampler = CandidateSampler(box_extent=0.1, z_box_factors=(0.8, 1.25), uv_fraction=0.3)
    obj = (150.0, 110.0, 30.0, 30.0)  # the object's box at the estimate: z_box = 1 m
    area = (60.0, 40.0, 200.0, 160.0)
    frame = Frame(np.zeros((H, W, 3), np.uint8), None, K, None, Region(obj, area, area, 4.0))
    t = sampler.translations(2000, frame, np.random.default_rng(0))
    u = K[0, 0] * t[:, 0] / t[:, 2] + K[0, 2]
    v = K[1, 1] * t[:, 1] / t[:, 2] + K[1, 2]
    border = 0.35 * 30.0  # a detection's slack around its central 0.3, of the object's box
    assert u.min() >= 60 + border - 1e-6 and u.max() <= 260 - border + 1e-6
    assert v.min() >= 40 + border - 1e-6 and v.max() <= 200 - border + 1e-6
    assert u.max() - u.min() > 150  # spread over the region, not the object's box
    assert 0.8 - 1e-9 <= t[:, 2].min() and t[:, 2].max() <= 1.25 + 1e-9
    with pytest.raises(ValueError, match="search region"):
        sampler.translations(3, Frame(frame.rgb, None, K), np.random.default_rng(0))


def _demo_rgb(n: int) -> list[np.ndarray]:
    return [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in demo_frames(n)]


def _inside(gt, region) -> float:
    """The share of box ``gt``'s area inside ``region`` (both x, y, w, h)."""
    x0, y0 = max(gt[0], region[0]), max(gt[1], region[1])
    x1, y1 = min(gt[0] + gt[2], region[0] + region[2]), min(gt[1] + gt[3], region[1] + region[3])
    return max(x1 - x0, 0) * max(y1 - y0, 0) / (gt[2] * gt[3])


@pytest.mark.parametrize("method", ["chpf", "poserbpf"])
def test_tracker_step_without_boxes_searches_around_its_estimate_on_the_demo(method):
    frames = _demo_rgb(6)
    tracker = Tracker.from_bundle(shipped_bundle(), method=method, n_particles=10)
    results = [
        tracker.step(rgb, K=DEMO_K, box=demo_box(1) if i == 0 else None)
        for i, rgb in enumerate(frames)
    ]
    assert results[0].region is None and all(r.weighed for r in results)
    for i, r in enumerate(results[1:], start=2):
        # the search region is the estimate's box (+ margin), which stays on the object
        gt = demo_box(i)
        assert r.region is not None and _inside(gt, r.region) > 0.8, (i, r.region, gt)
        assert r.region[2] * r.region[3] < 4 * gt[2] * gt[3], (i, r.region, gt)
        assert r.ok and 0.4 < r.t[2] < 1.0
    # with box_source detections the same frames are predict-only, as before
    tracker = Tracker.from_bundle(
        shipped_bundle(), method=method, n_particles=10, search={"box_source": "detections"}
    )
    old = [
        tracker.step(rgb, K=DEMO_K, box=demo_box(1) if i == 0 else None)
        for i, rgb in enumerate(frames)
    ]
    assert [r.weighed for r in old] == [True] + [False] * 5
    assert all(r.region is None for r in old)
    np.testing.assert_array_equal(old[-1].t, old[0].t)


@pytest.mark.parametrize("source", [None, "detections"])
def test_chpf_track_image_folder_with_init_box_searches_the_other_frames(
    source, images, camera, tmp_path, capsys
):
    out = tmp_path / "out"
    chosen = [] if source is None else ["--box-source", source]
    argv = ["--bundle", shipped_bundle(), "--images", images, "--camera", camera]
    argv += ["--init-box", ",".join(f"{v:g}" for v in demo_box(1)), "--out", out]
    argv += ["--poses", out / "poses.jsonl", "--n-particles", "10", "--no-progress", "--no-plot"]
    assert main([str(a) for a in argv + chosen]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    log = read_log(out / "log_chpf.csv")
    assert [int(r.values["has_box"]) for r in log] == [1, 0, 0, 0]
    poses = [json.loads(line) for line in (out / "poses.jsonl").read_text().splitlines()]
    if source is None:  # auto: the frames after the first are searched around the estimate
        assert "search.box_source auto" in first
        assert [int(r.values["weighed"]) for r in log] == [1, 1, 1, 1]
        assert poses[0]["region"] is None and all(len(d["region"]) == 4 for d in poses[1:])
        for d, i in zip(poses[1:], range(2, 5), strict=True):
            assert _inside(demo_box(i), d["region"]) > 0.8
    else:  # today's behaviour: predict only
        assert "search.box_source detections" in first and "predict-only" in first
        assert [int(r.values["weighed"]) for r in log] == [1, 0, 0, 0]
        assert all(d["region"] is None for d in poses)
