"""The silhouette (chpf.tracking.silhouette): hull samples, gradients, the outline's
calibration, its edges and region contrast, and the counter-evidence C_sil."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import DEMO_K, DEMO_ROOT

from chpf.bop import BopDataset
from chpf.bundle import Bundle
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.model_outline import outline_points
from chpf.tracking.silhouette import (
    SilhouetteEdges,
    SilhouetteRegion,
    colour_codes,
    hull_samples,
    outline_scale,
    sample_bilinear,
    silhouette_counter_evidence,
)


def test_hull_samples_lie_on_each_hull_with_outward_unit_normals() -> None:
    square = np.array([[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0], [20.0, 20.0]])
    triangle = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [5.0, 5.0], [1.0, 1.0]])
    points, normals = hull_samples(np.stack([triangle, square]), 40)
    # the triangle (perimeter 120): samples 3 pixels apart on its three sides
    tri, tri_n = points[0], normals[0]
    on_side = np.minimum(np.abs(tri[:, 0]), np.abs(tri[:, 1]))
    on_side = np.minimum(on_side, np.abs(tri[:, 0] / 40.0 + tri[:, 1] / 30.0 - 1.0) * 24.0)
    assert np.allclose(on_side, 0.0, atol=1e-9)
    assert np.all(np.sum((tri - [40 / 3, 10.0]) * tri_n, axis=1) > 0)
    points, normals = points[1], normals[1]
    on_edge = np.minimum(np.abs(points - 10.0), np.abs(points - 30.0)).min(axis=1)
    assert np.allclose(on_edge, 0.0, atol=1e-9)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    assert np.all(np.sum((points - 20.0) * normals, axis=1) > 0)  # outward
    # evenly spaced: 40 samples over a perimeter of 80 pixels, 10 on each side
    sides = np.argmin(np.abs(np.concatenate([points - 10.0, points - 30.0], axis=1)), axis=1)
    assert np.bincount(sides, minlength=4).tolist() == [10, 10, 10, 10]


def test_sample_bilinear_interpolates_and_is_zero_outside() -> None:
    ys, xs = np.mgrid[0:8, 0:10].astype(np.float32)
    grad = np.stack([xs, 2.0 * ys])  # (2,H,W)
    at = np.array([[2.5, 3.25], [0.0, 0.0], [-1.0, 2.0], [9.5, 1.0]])
    got = sample_bilinear(grad, at)
    assert np.allclose(got[0], [2.5, 6.5])
    assert np.allclose(got[1], [0.0, 0.0])
    assert np.allclose(got[2:], 0.0)  # outside the image


def test_counter_evidence_is_the_share_below_the_best_alignment() -> None:
    a = np.array([0.2, 0.4, 0.1, 0.0])
    assert np.allclose(silhouette_counter_evidence(a, 1.0), [0.5, 0.0, 0.75, 1.0])
    assert np.allclose(silhouette_counter_evidence(a, 2.0), [0.75, 0.0, 0.9375, 1.0])
    assert np.allclose(silhouette_counter_evidence(np.zeros(3), 1.0), 0.0)  # no edge anywhere


def test_colour_codes_bin_each_channel() -> None:
    rgb = np.array([[[0, 0, 0], [255, 255, 255], [64, 128, 0]]], dtype=np.uint8)
    assert colour_codes(rgb, 4).tolist() == [[0, 63, 1 * 16 + 2 * 4 + 0]]


def test_region_contrast_is_highest_where_the_outline_separates_the_colours() -> None:
    """A red square (half side 25 px at 1 m) on a striped background: at the true depth the
    inner band is all red and the outer all stripes (contrast 1); 15 % nearer or farther, one
    band mixes both (contrast below 1), and a pose beside the square sees stripes in both."""
    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])
    rgb = np.zeros((100, 200, 3), dtype=np.uint8)
    rgb[:, ::3] = (0, 0, 255)  # stripes of blue and green, one pixel and two
    rgb[:, 1::3] = (0, 255, 0)
    rgb[:, 2::3] = (0, 255, 0)
    rgb[25:76, 25:76] = (255, 0, 0)
    corners = np.array([[x, y, 0.0] for x in (-0.25, 0.25) for y in (-0.25, 0.25)])
    t = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.85], [0.0, 0.0, 1.15], [0.9, 0.0, 1.0]])
    a = SilhouetteRegion(corners).alignment(rgb, K, np.repeat(np.eye(3)[None], 4, 0), t, 0.05)
    assert a[0] == pytest.approx(1.0)
    assert np.all(a[1:3] < 0.9)
    assert a[3] < 0.1
    assert np.all((a >= 0.0) & (a <= 1.0))


@pytest.fixture(scope="module")
def box_bundle() -> Bundle:
    return Bundle.load(shipped_bundle(), spin=False)


def test_outline_scale_shrinks_the_hull_of_the_codebook_pixels(box_bundle: Bundle) -> None:
    """The hull of back-projected depth pixels is larger than the object (each pixel counts
    when half of its block is covered); the scale takes that back by a few per cent."""
    scale = outline_scale(box_bundle, outline_points(box_bundle))
    assert 0.94 < scale < 0.995


def _unoccluded_depth_triples() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(rgb, R (3,3,3), t (3,3)) of every third demo frame with the box >= 90 % visible: its
    true pose 5 % nearer, at and 5 % farther than the true depth."""
    scene = BopDataset(DEMO_ROOT).scene("test", 1)
    factors = np.array([0.95, 1.0, 1.05])
    out = []
    for im in scene.image_ids()[::3]:
        i, gt = next((i, g) for i, g in enumerate(scene.gt[im]) if g.obj_id == 2)
        if scene.gt_info[im][i].visib_fract >= 0.9:
            R = np.repeat(np.asarray(gt.R)[None], 3, axis=0)
            out.append((scene.rgb(im), R, np.asarray(gt.t)[None] * factors[:, None]))
    return out


def test_the_outline_meets_the_edges_best_at_the_true_depth(box_bundle: Bundle) -> None:
    """On the demo sequence's unoccluded frames the calibrated outline meets the image's edges
    better at the true pose than 5 % nearer or farther; the raw hull (scale 1) is too large and
    prefers the farther pose."""
    points = outline_points(box_bundle)
    edges = SilhouetteEdges(points * outline_scale(box_bundle, points))
    raw = SilhouetteEdges(points)
    frames = _unoccluded_depth_triples()
    wins = sum(
        int(np.argmax(edges.alignment(rgb, DEMO_K, R, t, 0.05)) == 1) for rgb, R, t in frames
    )
    raw_far = sum(
        int(np.argmax(raw.alignment(rgb, DEMO_K, R, t, 0.05)) == 2) for rgb, R, t in frames
    )
    assert len(frames) >= 5
    assert wins >= 0.7 * len(frames)
    assert raw_far >= 0.5 * len(frames)


def test_the_region_contrast_peaks_at_the_true_depth(box_bundle: Bundle) -> None:
    """On the demo sequence's unoccluded frames the outline separates the box's colours from
    the background's best at the true pose, not 5 % nearer or farther."""
    points = outline_points(box_bundle)
    region = SilhouetteRegion(points * outline_scale(box_bundle, points))
    frames = _unoccluded_depth_triples()
    wins = sum(
        int(np.argmax(region.alignment(rgb, DEMO_K, R, t, 0.05)) == 1) for rgb, R, t in frames
    )
    assert len(frames) >= 5
    assert wins >= 0.8 * len(frames)


@pytest.mark.parametrize("cue", ["region", "edges"])
def test_chpf_c_silhouette_doubts_a_pose_off_in_depth(box_bundle: Bundle, cue: str) -> None:
    """With ``chpf.c_silhouette`` the poses 8 % nearer and farther than the truth get more
    counter-evidence than the classifier alone gives them, the true pose none more."""
    from chpf.tracking.bundle_likelihood import BundleLikelihood
    from chpf.tracking.types import Frame

    scene = BopDataset(DEMO_ROOT).scene("test", 1)
    gt = next(g for g in scene.gt[1] if g.obj_id == 2)
    frame = Frame(rgb=scene.rgb(1), depth=None, K=DEMO_K)
    R = np.repeat(np.asarray(gt.R)[None], 3, axis=0)
    t = np.asarray(gt.t)[None] * np.array([1.0, 0.92, 1.08])[:, None]
    plain = BundleLikelihood(box_bundle, c_mode="learned").score(frame, R, t).C
    with_sil = BundleLikelihood(box_bundle, c_mode="learned", c_silhouette=1.0, silhouette_cue=cue)
    C = with_sil.score(frame, R, t).C
    assert C[0] == pytest.approx(plain[0])
    assert np.all(C[1:] > plain[1:] + 0.05)


def test_the_reference_takes_part_in_the_silhouettes_comparison(box_bundle: Bundle) -> None:
    """With a reference, the box's single-frame estimate is scored with the hypotheses: a set
    that is all 15-25 % too far gets C_sil from the estimate's better outline (without the
    reference its best member would get none), and the estimate's own C_sil joins C_ref."""
    from chpf.tracking.bundle_likelihood import BundleLikelihood
    from chpf.tracking.types import Frame

    scene = BopDataset(DEMO_ROOT).scene("test", 1)
    i, gt = next((i, g) for i, g in enumerate(scene.gt[1]) if g.obj_id == 2)
    frame = Frame(rgb=scene.rgb(1), depth=None, K=DEMO_K, box=scene.gt_info[1][i].bbox_visib)
    R = np.repeat(np.asarray(gt.R)[None], 3, axis=0)
    t = np.asarray(gt.t)[None] * np.array([1.15, 1.2, 1.25])[:, None]
    kwargs = {"c_mode": "learned", "c_silhouette": 1.0}
    alone = BundleLikelihood(box_bundle, **kwargs).score(frame, R, t)
    plain = BundleLikelihood(box_bundle, reference="box").score(frame, R, t)
    judged = BundleLikelihood(box_bundle, reference="box", **kwargs).score(frame, R, t)
    best = int(np.argmin(alone.C))
    assert judged.C[best] > alone.C[best] + 0.2
    assert judged.reference[0] == pytest.approx(plain.reference[0])
    assert judged.reference[1] >= plain.reference[1]


def test_the_search_region_fits_a_too_far_estimate_to_the_outline(box_bundle: Bundle) -> None:
    """First box only: an estimate 8 % too far projects a box 8 % too small; fitted to the
    outline's colour contrast (search.fit_depths) the region's box comes within 5 % of the true
    pose's on most of the demo's unoccluded frames."""
    from chpf.tracking.bundle_likelihood import BundleLikelihood
    from chpf.tracking.search_region import SearchConfig, SearchRegion, projected_box
    from chpf.tracking.types import Frame

    likelihood = BundleLikelihood(box_bundle, c_silhouette=1.0)
    search = SearchRegion(SearchConfig(box_source="estimate"), likelihood.outline, None, likelihood)
    ratios = []
    for rgb, R, t in _unoccluded_depth_triples():
        true_side = projected_box(likelihood.outline, R[1], t[1], DEMO_K)[2]
        frame = search.frame(
            Frame(rgb, None, DEMO_K), (R[1], 1.08 * t[1]), np.random.default_rng(0)
        )
        assert frame.region.fitted
        ratios.append(frame.region.box[2] / true_side)
    ratios = np.array(ratios)
    assert np.mean(np.abs(ratios - 1.0) < 0.05) >= 0.8
