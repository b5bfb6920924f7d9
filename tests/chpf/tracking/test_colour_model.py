"""The colour model learned while tracking: its histograms, posterior and box contrast."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.tracking.colour_model import BINS, ColourModel, hull_mask, stride

H, W = 120, 160
RED, TEAL, GREY = (200, 30, 30), (20, 120, 120), (90, 90, 90)


def _scene(x: int, y: int, side: int = 30) -> np.ndarray:
    """A red square of ``side`` pixels at (x, y) on a background of teal and grey stripes."""
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[:] = TEAL
    rgb[:, ::8] = GREY
    rgb[y : y + side, x : x + side] = RED
    return rgb


def _corners(x: int, y: int, side: int = 30) -> np.ndarray:
    return np.array([[x, y], [x + side - 1, y], [x + side - 1, y + side - 1], [x, y + side - 1]])


def _box(cx: float, cy: float, side: float = 30.0) -> np.ndarray:
    return np.array([cx - side / 2, cy - side / 2, side, side])


def test_hull_mask_fills_the_hull_and_grows_by_a_share_of_its_side():
    mask = hull_mask(_corners(20, 30, 20), H, W)
    assert mask.sum() == 400 and mask[30, 20] and not mask[29, 20]
    grown = hull_mask(_corners(20, 30, 20), H, W, grow=0.25)  # 5 px on each side
    assert grown[25, 25] and grown[35, 15] and not grown[24, 25] and grown.sum() > 800


def test_a_taught_model_finds_the_object_where_it_moved_and_nothing_on_the_background():
    model = ColourModel()
    assert not model.ready and model.box_contrast(_scene(20, 20), _box(35, 35))[0] == 0.0
    model.teach(_scene(20, 20), _corners(20, 20))
    assert model.ready
    jumped = _scene(110, 70)  # the object elsewhere: where it was is background now
    posterior = model.posterior(jumped)
    assert posterior[80, 120] == pytest.approx(1.0) and posterior[30, 30] == pytest.approx(0.0)
    scores = model.box_contrast(jumped, np.stack([_box(125, 85), _box(35, 35), _box(60, 90)]))
    assert scores[0] > 0.9 and abs(scores[1]) < 0.05 and abs(scores[2]) < 0.05
    half = model.box_contrast(jumped, _box(110, 85))[0]  # half on the object
    assert 0.1 < half < scores[0]


def test_an_unseen_colour_is_even_and_a_new_image_gets_its_own_posterior():
    model = ColourModel()
    model.teach(_scene(20, 20), _corners(20, 20))
    blue = np.zeros((H, W, 3), np.uint8)
    blue[:] = (10, 10, 240)
    assert np.all(model.posterior(blue) == 0.5)
    assert model.posterior(_scene(20, 20))[30, 30] == pytest.approx(1.0)
    assert model.posterior(_scene(100, 20))[30, 30] == pytest.approx(0.0)  # not the last map


def test_teaching_keeps_a_running_mean_at_its_rate_and_reset_forgets():
    model = ColourModel(rate=0.25)
    model.teach(_scene(20, 20), _corners(20, 20))
    red_bin = (RED[0] // (256 // BINS) * BINS + RED[1] // (256 // BINS)) * BINS + RED[2] // (
        256 // BINS
    )
    assert model.object_hist[red_bin] == pytest.approx(1.0)
    green = _scene(20, 20)
    green[20:50, 20:50] = (30, 200, 30)
    model.teach(green, _corners(20, 20))
    assert model.object_hist[red_bin] == pytest.approx(0.75)
    assert model.object_hist.sum() == pytest.approx(1.0)
    model.teach(green, np.array([[-50, -50], [-40, -50], [-40, -40]]))  # off the image
    assert model.object_hist[red_bin] == pytest.approx(0.75)
    model.reset()
    assert not model.ready


def test_a_large_image_is_read_at_a_stride_and_scores_as_the_small_one():
    """A frame four times as large (each pixel a 4 x 4 block) is read every 4th pixel: the same
    histograms, and the same contrast for boxes four times as large."""
    small, large = ColourModel(), ColourModel()
    small.teach(_scene(20, 20), _corners(20, 20))
    big = np.repeat(np.repeat(_scene(20, 20), 4, axis=0), 4, axis=1)  # 640 x 480
    assert stride(big.shape[1]) == 2 and stride(W) == 1
    huge = np.repeat(np.repeat(big, 2, axis=0), 2, axis=1)  # 1280 x 960: stride 4
    large.teach(huge, _corners(20, 20) * 8)
    assert large.posterior(huge).shape == (240, 320)
    np.testing.assert_allclose(large.object_hist, small.object_hist, atol=0.02)
    jumped = _scene(110, 70)
    boxes = np.stack([_box(125, 85), _box(35, 35), _box(110, 85)])
    huge_jumped = np.repeat(np.repeat(jumped, 8, axis=0), 8, axis=1)
    np.testing.assert_allclose(
        large.box_contrast(huge_jumped, boxes * 8), small.box_contrast(jumped, boxes), atol=0.05
    )
