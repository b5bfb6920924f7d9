"""The overlay's drawing: the bundle's outline points and the outline and bar on a frame."""

from __future__ import annotations

import json

import numpy as np

from chpf.bop import read_rgb
from chpf.bundle import Bundle
from chpf.objects import get_object
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.model_outline import outline_points
from chpf.tracking.overlay import doubt, draw_overlay
from chpf.tracking.types import TrackResult
from tests.helpers import DEMO_K, DEMO_SCENE, demo_box, demo_frames


def test_outline_points_from_the_codebook_depth_span_the_object():
    """The shipped bundle's object is the built-in box: the back-projected depth crops span its
    mesh's bounds within a few millimetres (the depth crops are 32 px for 32 cm)."""
    pts = outline_points(Bundle.load(shipped_bundle()))
    bounds = get_object("box").mesh.bounds
    np.testing.assert_allclose(pts.min(axis=0), bounds[0], atol=0.006)
    np.testing.assert_allclose(pts.max(axis=0), bounds[1], atol=0.006)
    assert 8 <= len(pts) < 2000  # hull vertices, not the whole cloud


def test_outline_at_the_true_pose_surrounds_the_object_and_the_bar_shows_alpha():
    gt = json.loads((DEMO_SCENE / "scene_gt.json").read_text())["1"][0]
    R = np.array(gt["cam_R_m2c"]).reshape(3, 3)
    t = np.array(gt["cam_t_m2c"]) / 1000.0
    rgb = read_rgb(demo_frames(1)[0])
    pts = outline_points(Bundle.load(shipped_bundle()))
    result = TrackResult(R, t, 0.75, 1.0, 1.0, 10.0, {}, True)
    img = draw_overlay(rgb, DEMO_K, R, t, pts, 0.0, "chpf  frame 1", doubt(result, 50))
    drawn = np.any(img != rgb, axis=-1)
    drawn[:40] = False  # the title and bar panel (the object starts at row 48)
    ys, xs = np.nonzero(drawn)  # the outline (the axes, 0 m long, are a dot inside it)
    x, y, w, h = demo_box(1)  # the visible box (fully visible in frame 1)
    assert abs(xs.min() - x) <= 3 and abs(ys.min() - y) <= 3
    assert abs(xs.max() - (x + w - 1)) <= 3 and abs(ys.max() - (y + h - 1)) <= 3
    assert doubt(result, 50)[:2] == (0.75, "alpha 0.75")
    no_alpha = TrackResult(R, t, float("nan"), 1.0, 1.0, 10.0, {}, True)
    assert doubt(no_alpha, 50) == (0.2, "ESS 10/50", False)
    blank = draw_overlay(rgb, DEMO_K, None, None, pts, 0.1, "chpf", None)
    assert np.array_equal(blank[40:], rgb[40:])  # no estimate: nothing drawn on the object
