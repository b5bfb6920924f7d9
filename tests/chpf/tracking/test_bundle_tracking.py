"""Likelihoods from a model bundle and the Tracker API, on rendered frames with a template bundle
(see conftest.py: real geometry and ONNX, no training)."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from chpf.bundle import Bundle
from chpf.errors import BundleError, ConfigError, ImageSizeError
from chpf.geometry import (
    allocentric_to_egocentric,
    axis_angle_to_matrix,
    egocentric_to_allocentric,
    geodesic_angle,
    random_rotations,
)
from chpf.metrics import add, adds
from chpf.objects import get_object
from chpf.tracking.bundle_likelihood import (
    BundleLikelihood,
    anchored_boxes,
    box_counter_evidence,
    edge_counter_evidence,
    likelihood_from_cosine,
)
from chpf.tracking.codebook_candidates import CodebookRotations
from chpf.tracking.depth_scores import depth_scores
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import Frame, Region

PAPER = Path(__file__).resolve().parents[3] / "configs" / "track_paper.yaml"
"""The paper's setting: blind phi_cand, sums over every particle (the default is informed)."""


def test_depth_scores_count_the_right_pixels():
    cb = np.zeros((3, 4, 4), np.float32)
    cb[:, :2, :] = 1.0  # object on the top 8 pixels, at D_r = 1.0
    meas = np.full((3, 4, 4), 0.5, np.float32)
    meas[0, 0, :] = 0.0  # 4 holes in hypothesis 0
    meas[1, :2, :2] = 0.7  # hypothesis 1: 4 pixels measured 0.2 m behind the surface
    meas[2] = 0.0  # hypothesis 2: no depth at all
    d = depth_scores(meas, cb, z=np.array([0.5, 0.5, 0.5]), render_distance=1.0, no_data=0.25)
    np.testing.assert_allclose(d.L, [1.0, 0.5, 0.25])
    np.testing.assert_allclose(d.C, [0.0, 0.5, 0.25])
    np.testing.assert_array_equal(d.valid, [4, 8, 0])
    # measured in front of the surface (an occluder) is not counter-evidence
    d = depth_scores(np.full((1, 4, 4), 0.3, np.float32), cb[:1], np.array([0.5]), 1.0)
    assert d.L[0] == 0.0 and d.C[0] == 0.0


@pytest.fixture(scope="module")
def bundle(template_bundle):
    return Bundle.load(template_bundle)


def _hypotheses(seq, i, rng, n=16):
    R_true = np.repeat(seq.R[i : i + 1], n, 0)
    t_true = np.repeat(seq.t[i : i + 1], n, 0)
    return {
        "truth": (R_true, t_true),
        "random": (random_rotations(n, rng), t_true + rng.normal(0, 0.03, (n, 3))),
        "closer": (R_true, t_true * 0.85),
        "farther": (R_true, t_true * 1.15),
    }


def test_bundle_likelihood_prefers_the_true_pose(bundle, rendered_sequence):
    seq = rendered_sequence
    like = BundleLikelihood(bundle, sigma=0.1, c_mode="learned")
    frame = Frame(seq.rgb[0], None, seq.K, seq.box(0))
    s = {
        k: like.score(frame, R, t)
        for k, (R, t) in _hypotheses(seq, 0, np.random.default_rng(0)).items()
    }
    assert s["truth"].L.min() > 0.6 > s["random"].L.mean()
    assert s["truth"].w.mean() > 10 * s["random"].w.mean()
    assert s["truth"].C.max() < 0.2 < s["random"].C.mean()
    for sc in s.values():
        assert sc.L.shape == sc.w.shape == sc.C.shape == (16,)
        assert np.all((sc.L >= 0) & (sc.L <= 1) & (sc.C >= 0) & (sc.C <= 1))
    assert {"crop", "encode", "lookup", "head"} <= set(s["truth"].stage_ms)
    assert "ch_encode" not in s["truth"].stage_ms  # shared encoder: one pass for L and C


def test_c_box_counts_a_hypothesis_smaller_than_the_detection_box_as_misaligned(
    bundle, rendered_sequence
):
    """The true pose moved along its ray: nearer (projects larger than the box, as an occluded
    object's box would) keeps C; 1.5 x farther projects at 2/3 of the box: C_box = 1, C = 1;
    1.25 x farther: rho ~1.25, C_box ~0.25 with the ramp's margin 0.2, combined by noisy-or."""
    seq = rendered_sequence
    frame = Frame(seq.rgb[0], None, seq.K, seq.box(0))
    scales = np.array([0.8, 1.0, 1.25, 1.5])
    R, t = np.repeat(seq.R[:1], 4, 0), seq.t[0][None] * scales[:, None]
    plain = BundleLikelihood(bundle, c_mode="learned").score(frame, R, t).C
    boxed = BundleLikelihood(bundle, c_mode="learned", c_box=0.2, c_box_shape="ramp")
    boxed = boxed.score(frame, R, t).C
    np.testing.assert_allclose(boxed[:2], plain[:2])
    assert boxed[3] == pytest.approx(1.0) and plain[3] < 0.9
    assert plain[2] < boxed[2] < 1.0
    no_box = Frame(seq.rgb[0], None, seq.K, None)
    np.testing.assert_allclose(
        BundleLikelihood(bundle, c_box=0.2).score(no_box, R, t).C,
        BundleLikelihood(bundle).score(no_box, R, t).C,
    )


def test_c_box_reads_a_fitted_search_regions_box_as_a_detections(bundle, rendered_sequence):
    """Without a detection, a search region whose box was fitted to the image measures the
    object's size as a detection does: the pose 1.5 x too far gets C_box; an unfitted region's
    box (the estimate's own projection) measures nothing."""
    seq = rendered_sequence
    R, t = np.repeat(seq.R[:1], 2, 0), seq.t[0][None] * np.array([1.0, 1.5])[:, None]
    region = Region(seq.box(0), seq.box(0), seq.box(0))
    boxed = BundleLikelihood(bundle, c_box=0.2, c_box_shape="ramp")
    C = {
        name: boxed.score(Frame(seq.rgb[0], None, seq.K, None, r), R, t).C
        for name, r in (("fitted", replace(region, fitted=True)), ("plain", region))
    }
    detected = boxed.score(Frame(seq.rgb[0], None, seq.K, seq.box(0)), R, t).C
    np.testing.assert_allclose(C["fitted"], detected)
    assert C["fitted"][1] == pytest.approx(1.0) and C["plain"][1] < 0.9


def test_c_box_does_not_count_the_true_pose(bundle, rendered_sequence):
    """The projected side comes from the model's outline at the particle's own pose: with each
    codebook entry's extent instead, the template bundle's coarse grid (512 entries, the
    nearest 15-19 deg off) made the truth project 12-19 % smaller than its box and C_box 0.5-0.8
    there."""
    seq = rendered_sequence
    plain, boxed = BundleLikelihood(bundle), BundleLikelihood(bundle, c_box=0.1)
    for i in range(0, 21, 5):
        frame = Frame(seq.rgb[i], None, seq.K, seq.box(i))
        R, t = seq.R[i : i + 1], seq.t[i : i + 1]
        assert boxed.score(frame, R, t).C[0] < plain.score(frame, R, t).C[0] + 0.05


def test_c_box_each_side_reads_a_cut_side_as_occlusion_and_a_whole_box_both_ways(
    bundle, rendered_sequence
):
    """c_box_sides "each": a side of the box longer than the projection's counts in C (too far);
    with box_whole q each side shorter than the projection's weighs w by 1 - q C_box(1 / rho):
    a box whole on both sides weighs a hypothesis too near down, one cut on a side by an
    occluder weighs every depth by about 1 - q on that side, and its other side still counts a
    hypothesis too far."""
    seq = rendered_sequence
    scales = np.array([0.85, 1.0, 1.2])
    R, t = np.repeat(seq.R[:1], 3, 0), seq.t[0][None] * scales[:, None]
    plain = BundleLikelihood(bundle, c_mode="learned")
    each = BundleLikelihood(bundle, c_mode="learned", c_box=0.1, c_box_sides="each", box_whole=0.5)
    x, y, w, h = each.outline_box(seq.R[0], seq.t[0], seq.K)
    for name, box in (("whole", (x, y, w, h)), ("cut", (x + 0.4 * w, y, 0.6 * w, h))):
        frame = Frame(seq.rgb[0], None, seq.K, box)
        p, e = plain.score(frame, R, t), each.score(frame, R, t)
        factor = e.w / p.w
        np.testing.assert_allclose(e.C[:2], p.C[:2])  # no side longer than its projection
        assert e.C[2] > 0.8 > p.C[2]  # 1.2 x farther: both sides (the cut one's height) too long
        if name == "whole":
            assert factor[1] == pytest.approx(1.0, abs=1e-6) and factor[0] < 0.45
        else:
            assert factor[1] == pytest.approx(0.5, abs=0.01) and factor[0] < factor[1]
    larger = BundleLikelihood(bundle, c_mode="learned", c_box=0.1, box_whole=0.5)
    whole_box = Frame(seq.rgb[0], None, seq.K, (x, y, w, h))
    factor = larger.score(whole_box, R, t).w / plain.score(whole_box, R, t).w
    # the larger side alone: one factor 1 - q C_box(1 / rho), rho about 0.85 (0.63), not two
    assert factor[1] == pytest.approx(1.0, abs=1e-6) and 0.55 < factor[0] < 0.7
    with pytest.raises(ConfigError, match="c_box_sides must be one of"):
        BundleLikelihood(bundle, c_box=0.1, c_box_sides="both")
    with pytest.raises(ConfigError, match="box_whole must be in"):
        BundleLikelihood(bundle, c_box=0.1, box_whole=1.5)


def test_box_counter_evidence_gauss_counts_depth_errors_inside_the_ramps_margin():
    """gauss: 1 - exp(-ln(rho)^2 / (2 s^2)) above rho 1; ramp: nothing below 1 + m. A belief 10 %
    too far (rho 1.1) is counted by gauss (s 0.1) and not by the ramp (m 0.2); a larger
    projection (rho < 1: occlusion explains it) by neither."""
    rho = np.array([0.5, 1.0, 1.1, 1.25])
    gauss = box_counter_evidence(rho, 0.1, "gauss")
    expected = 1 - np.exp(-0.5 * (np.log(rho[2:]) / 0.1) ** 2)
    np.testing.assert_allclose(gauss, [0.0, 0.0, *expected])
    assert 0.3 < gauss[2] < 0.4 and gauss[3] > 0.9
    np.testing.assert_allclose(box_counter_evidence(rho, 0.2, "ramp"), [0.0, 0.0, 0.0, 0.25])


def test_edge_counter_evidence_is_a_ramp_above_its_margin():
    overshoot = np.array([-0.3, 0.0, 0.2, 0.3, 0.4, 0.9])
    np.testing.assert_allclose(edge_counter_evidence(overshoot, 0.2), [0, 0, 0, 0.5, 1, 1])


def test_c_edge_counts_a_hypothesis_that_leaves_the_detection_box_outside(
    bundle, rendered_sequence
):
    """The truth moved sideways by 0.3 and 0.6 of the box's side leaves about that much of the
    detection box outside its projection: C_edge between 0 and 1, and 1 (margin 0.2). The
    truth, the truth nearer (a larger projection) and the truth against a box of its left half
    (the visible part of an occluded object) contain the box: C_edge 0. C_edge stays out of C
    (the weights), and there is none without a box or with c_edge off."""
    seq = rendered_sequence
    box = seq.box(0)
    frame = Frame(seq.rgb[0], None, seq.K, box)
    side_m = max(box[2], box[3]) * seq.t[0, 2] / seq.K[0, 0]
    t = np.repeat(seq.t[:1], 4, 0)
    t[1, 0] += 0.3 * side_m
    t[2, 0] -= 0.6 * side_m
    t[3] *= 0.8
    R = np.repeat(seq.R[:1], 4, 0)
    edged = BundleLikelihood(bundle, c_edge=0.2)
    s = edged.score(frame, R, t)
    assert s.C_edge is not None
    assert s.C_edge[0] == 0.0 and s.C_edge[3] == 0.0
    assert 0.2 < s.C_edge[1] < 1.0 and s.C_edge[2] == 1.0
    np.testing.assert_allclose(s.C, BundleLikelihood(bundle).score(frame, R, t).C)
    left_half = Frame(seq.rgb[0], None, seq.K, (box[0], box[1], box[2] / 2, box[3]))
    assert edged.score(left_half, R[:1], t[:1]).C_edge[0] == 0.0
    no_box = Frame(seq.rgb[0], None, seq.K, None)
    assert edged.score(no_box, R, t).C_edge is None
    assert BundleLikelihood(bundle).score(frame, R, t).C_edge is None


def test_c_near_counts_a_hypothesis_that_projects_past_the_box_on_all_four_sides(
    bundle, rendered_sequence
):
    """The truth at 0.7 of its depth projects 1.4 times larger, past the detection box on
    every side by more than a tenth of its side: C_edge > 0.5 with c_near 0.05 (0 without). The
    truth, and the truth against a box of its left half (an occluded object), do not."""
    seq = rendered_sequence
    box = seq.box(0)
    frame = Frame(seq.rgb[0], None, seq.K, box)
    t = np.stack([seq.t[0], 0.7 * seq.t[0]])
    R = np.repeat(seq.R[:1], 2, 0)
    near = BundleLikelihood(bundle, c_edge=0.2, c_near=0.05)
    C_edge = near.score(frame, R, t).C_edge
    assert C_edge is not None and C_edge[0] == 0.0 and C_edge[1] > 0.5
    assert BundleLikelihood(bundle, c_edge=0.2).score(frame, R, t).C_edge[1] == 0.0
    left_half = Frame(seq.rgb[0], None, seq.K, (box[0], box[1], box[2] / 2, box[3]))
    assert near.score(left_half, R[:1], t[:1]).C_edge[0] == 0.0


def test_codebook_scores_give_the_box_edge_evidence_of_an_entry(bundle, rendered_sequence):
    """CH-RBPF's C_edge: the truth's nearest entry at the true translation contains the box,
    at a translation 0.6 box sides aside it does not."""
    seq = rendered_sequence
    box = seq.box(0)
    frame = Frame(seq.rgb[0], None, seq.K, box)
    aside = seq.t[0] + [0.6 * max(box[2], box[3]) * seq.t[0, 2] / seq.K[0, 0], 0.0, 0.0]
    t = np.stack([seq.t[0], aside])
    like = BundleLikelihood(bundle, c_edge=0.2)
    entry = bundle.nearest(egocentric_to_allocentric(seq.R[:1], seq.t[:1]))
    np.testing.assert_allclose(like.codebook_scores(frame, t).edge(np.repeat(entry, 2)), [0, 1])
    assert BundleLikelihood(bundle).codebook_scores(frame, t).edge(np.repeat(entry, 2)) is None


def test_l_from_cos_maps_the_cosine_to_the_unnormalised_likelihood(bundle, rendered_sequence):
    seq = rendered_sequence
    frame = Frame(seq.rgb[0], None, seq.K, seq.box(0))
    R, t = _hypotheses(seq, 0, np.random.default_rng(2))["random"]
    t = np.concatenate([t, [[0.0, 0.0, -0.5]]])  # the last one is behind the camera
    R = np.concatenate([R, seq.R[:1]])
    clip = BundleLikelihood(bundle, l_from_cos="clip").score(frame, R, t)
    affine = BundleLikelihood(bundle, l_from_cos="affine").score(frame, R, t)
    cos = 1.0 - 0.3 * np.sqrt(-2.0 * np.log(clip.w[:-1]))  # w = exp(-(1 - c)^2 / (2 sigma^2))
    np.testing.assert_allclose(clip.L[:-1], np.maximum(cos, 0.0), atol=1e-6)
    np.testing.assert_allclose(affine.L[:-1], 0.5 * (1.0 + cos), atol=1e-6)
    np.testing.assert_array_equal(affine.w, clip.w)  # the weights do not depend on it
    assert clip.L[-1] == affine.L[-1] == 0.0  # behind the camera: c = -1
    with pytest.raises(ConfigError):
        BundleLikelihood(bundle, l_from_cos="square")
    c = np.array([-1.0, -0.2, 0.0, 0.4, 1.0])
    np.testing.assert_allclose(likelihood_from_cosine(c, "clip"), [0.0, 0.0, 0.0, 0.4, 1.0])
    np.testing.assert_allclose(likelihood_from_cosine(c, "affine"), [0.0, 0.4, 0.5, 0.7, 1.0])


def test_separate_ch_encoder_runs_its_own_pass(template_bundle_split, rendered_sequence):
    seq = rendered_sequence
    like = BundleLikelihood(Bundle.load(template_bundle_split), c_mode="learned")
    frame = Frame(seq.rgb[0], None, seq.K, seq.box(0))
    s = like.score(frame, seq.R[:1], seq.t[:1])
    assert "ch_encode" in s.stage_ms and s.C[0] < 0.2
    # C is not computed when not asked for
    assert BundleLikelihood(like.bundle, c_mode="none").score(frame, seq.R[:1], seq.t[:1]).C is None


def test_depth_likelihoods_and_counter_hypothesis(bundle, rendered_sequence):
    seq = rendered_sequence
    like = BundleLikelihood(bundle, c_mode="depth", use_depth=True)
    depth = seq.depth[0].copy()
    depth[::3, ::2] = 0.0  # holes
    frame = Frame(seq.rgb[0], depth, seq.K, seq.box(0))
    h = _hypotheses(seq, 0, np.random.default_rng(1))
    s = {k: like.score(frame, R, t) for k, (R, t) in h.items()}
    # (the codebook's nearest view is up to ~10 degrees off: edges disagree a little)
    assert s["truth"].C.max() < 0.3 and s["truth"].L.min() > 0.4
    # a hypothesis in front of the measured surface: the sensor sees behind it -> C_depth high
    assert s["closer"].C.min() > 0.8
    # behind the measured surface: explained by an occluder -> C_depth low, but L_depth low too
    R_far, t_far = h["farther"]
    k_far = bundle.nearest(egocentric_to_allocentric(R_far, t_far))
    l_depth = like.depth_weight(frame, k_far, t_far)
    assert s["farther"].C.max() < 0.3 and l_depth.max() < 0.1
    assert "depth" in s["truth"].stage_ms
    # L_depth weighs the particles (w); L stays the appearance's, which the strategies compare
    # with C or with a fixed scale (before, L = L x L_depth held SRL's and CH-PF's alpha near 1)
    rgb_only = BundleLikelihood(bundle, c_mode="none").score(frame, R_far, t_far)
    np.testing.assert_array_equal(s["farther"].L, rgb_only.L)
    np.testing.assert_allclose(s["farther"].w, rgb_only.w * l_depth, rtol=1e-12)
    both = BundleLikelihood(bundle, c_mode="both", use_depth=True).score(frame, *h["closer"])
    learned = BundleLikelihood(bundle, c_mode="learned").score(frame, *h["closer"])
    np.testing.assert_allclose(both.C, 0.5 * (s["closer"].C + learned.C), atol=1e-6)
    with pytest.raises(ConfigError):
        BundleLikelihood(bundle, c_mode="depth", use_depth=False)


def test_hypotheses_behind_the_camera_or_off_the_image(bundle, rendered_sequence):
    seq = rendered_sequence
    like = BundleLikelihood(bundle, c_mode="learned", use_depth=True)
    frame = Frame(seq.rgb[0], seq.depth[0], seq.K, seq.box(0))
    R = np.repeat(seq.R[:1], 3, 0)
    t = np.array([[0.0, 0.0, -0.5], [0.0, 0.0, 0.0], [5.0, 0.0, 0.5]])
    s = like.score(frame, R, t)
    assert np.all(np.isfinite(s.L) & np.isfinite(s.w) & np.isfinite(s.C))
    assert s.L[0] == 0.0 and s.L[1] == 0.0 and s.C[0] == 1.0 and s.C[1] == 1.0
    assert s.L[2] < 0.2  # far off the image: a black crop matches nothing


def test_single_frame_estimate_from_the_box(bundle, rendered_sequence):
    seq = rendered_sequence
    like = BundleLikelihood(bundle)
    R, t = like.single_frame_estimate(Frame(seq.rgb[3], None, seq.K, seq.box(3)))
    assert abs(t[2] - seq.t[3, 2]) < 0.15 * seq.t[3, 2]
    assert np.linalg.norm(t[:2] - seq.t[3, :2]) < 0.03
    # R is the codebook entry with the best cosine over the whole codebook (at the box centre)
    cos = like.codebook_scores(Frame(seq.rgb[3], None, seq.K, None), t[None]).cos[0]
    k = int(np.argmax(cos))
    assert (
        np.degrees(geodesic_angle(R, allocentric_to_egocentric(bundle.grid.rotations[k], t))) < 1e-6
    )
    assert adds(get_object("box").points, R, t, seq.R[3], seq.t[3]) < 0.3 * bundle.obj_info.diameter
    assert like.single_frame_estimate(Frame(seq.rgb[3], None, seq.K, None)) is None


def test_box_centre_crop_rides_along_in_the_particles_encoder_pass(
    bundle, rendered_sequence, monkeypatch
):
    """Once box_centre_cosines has been asked for, score() encodes the box-centre crop with
    the particles' crops: the next box_centre_cosines of that frame gives the cosines of the
    crop encoded alone without another encoder pass, and score()'s own results do not change;
    a frame whose box-centre crop is another (another box, or the same image array changed in
    place) is encoded afresh."""
    seq = rendered_sequence
    frame = Frame(seq.rgb[3].copy(), None, seq.K, seq.box(3))
    x, y, w, h = seq.box(3)
    other = Frame(frame.rgb, None, seq.K, (x + 7.0, y, w, h))
    refilled = Frame(seq.rgb[10], None, seq.K, seq.box(3))
    rng = np.random.default_rng(0)
    R, t = _hypotheses(seq, 3, rng, n=8)["random"]
    alone = [BundleLikelihood(bundle).box_centre_cosines(f) for f in (frame, other, refilled)]
    plain = BundleLikelihood(bundle).score(frame, R, t)
    like = BundleLikelihood(bundle)
    like.box_centre_cosines(frame)
    sizes: list[int] = []
    embed = bundle.embed
    monkeypatch.setattr(bundle, "embed", lambda crops: sizes.append(len(crops)) or embed(crops))
    s = like.score(frame, R, t)
    cos, t0 = like.box_centre_cosines(frame)
    assert sizes == [9]
    np.testing.assert_array_equal(cos, alone[0][0])
    np.testing.assert_array_equal(t0, alone[0][1])
    for a, b in ((s.L, plain.L), (s.w, plain.w), (s.C, plain.C)):
        np.testing.assert_array_equal(a, b)
    like.score(frame, R, t)
    np.testing.assert_array_equal(like.box_centre_cosines(other)[0], alone[1][0])
    assert sizes == [9, 9, 1]
    like.score(frame, R, t)
    frame.rgb[...] = seq.rgb[10]  # the caller's buffer refilled in place
    np.testing.assert_array_equal(like.box_centre_cosines(frame)[0], alone[2][0])
    assert sizes == [9, 9, 1, 9, 1]


def test_the_frames_reference_is_the_best_codebook_entry_at_the_frames_box(
    bundle, rendered_sequence
):
    """reference "detection": Scores and CodebookScores carry (L_ref, C_ref), the best codebook
    entry's L for the crop at the detection box's centre and the classifier's C of that crop and
    entry; None without a detection and when off. Reference "box" takes, on a frame without a
    detection, the search region's box while it is not widened (Region.cue), none once it is."""
    from chpf.crops import crop_affines, extract_crops
    from chpf.tracking.types import Region

    seq = rendered_sequence
    frame = Frame(seq.rgb[3], None, seq.K, seq.box(3))
    R, t = _hypotheses(seq, 3, np.random.default_rng(0), n=4)["truth"]
    like = BundleLikelihood(bundle, reference="detection")
    s = like.score(frame, R, t)
    cos, t0 = BundleLikelihood(bundle).box_centre_cosines(frame)
    k = int(np.argmax(cos))
    crop = extract_crops(frame.rgb, crop_affines(t0[None], seq.K, bundle.spec), bundle.spec.size)
    emb = bundle.embed(crop) if bundle.shares_encoder else bundle.ch_embed(crop)
    assert s.reference == pytest.approx((max(cos[k], 0.0), bundle.p_misaligned(emb, [k])[0]))
    assert s.reference[0] > 0.6 and s.reference[1] < 0.5  # the whole box: recognised, aligned
    assert like.codebook_scores(frame, t).reference == pytest.approx(s.reference)
    region = Region(box=seq.box(3), area=seq.box(3), window=seq.box(3))
    searched = Frame(seq.rgb[3], None, seq.K, None, region)
    assert like.score(searched, R, t).reference is None
    assert BundleLikelihood(bundle).score(frame, R, t).reference is None
    boxed = BundleLikelihood(bundle, reference="box")
    assert boxed.score(searched, R, t).reference == pytest.approx(s.reference)
    assert boxed.codebook_scores(searched, t).reference == pytest.approx(s.reference)
    widened = Frame(
        seq.rgb[3],
        None,
        seq.K,
        None,
        Region(region.box, region.area, region.window, 2.0, cue=False),
    )
    assert boxed.score(widened, R, t).reference is None
    with pytest.raises(ConfigError, match="reference must be one of"):
        BundleLikelihood(bundle, reference="estimate")


def _track(tracker, seq, modality="rgb", frames=None, collapse_at=None, wall=None):
    """Errors (T,3) against the truth, columns ADD-S and ADD in diameters and the rotation error
    in degrees (inf without an estimate), and the TrackResults of ``tracker`` on ``seq``; at
    frame ``collapse_at`` every particle is first put on one wrong pose (90 deg off, 0.3
    diameters to the side). ``wall``: depth (m) of a background wall where ``seq`` has none."""
    pts = get_object(tracker.bundle.obj_info.name).points
    d = tracker.bundle.obj_info.diameter
    errs, res = [], []
    for i in frames if frames is not None else range(len(seq)):
        if i == collapse_at:
            wrong_R = axis_angle_to_matrix(np.array([0.0, np.pi / 2, 0.0])) @ seq.R[i]
            wrong_t = seq.t[i] + np.array([0.3 * d, 0.0, 0.0])
            n = tracker.filter.n
            tracker.filter.set_particles(
                np.repeat(wrong_R[None], n, 0), np.repeat(wrong_t[None], n, 0)
            )
        depth = seq.depth[i] if modality == "rgbd" else None
        if depth is not None and wall is not None:
            depth = np.where(depth > 0, depth, np.float32(wall))
        r = tracker.step(seq.rgb[i], depth=depth, K=seq.K, box=seq.box(i))
        res.append(r)
        if r.ok:
            errs.append(
                [
                    adds(pts, r.R, r.t, seq.R[i], seq.t[i]) / d,
                    add(pts, r.R, r.t, seq.R[i], seq.t[i]) / d,
                    np.degrees(geodesic_angle(r.R, seq.R[i])),
                ]
            )
        else:
            errs.append([np.inf, np.inf, np.inf])
    return np.array(errs), res


@pytest.mark.parametrize(
    ("method", "modality", "max_adds", "max_add", "max_deg", "config"),
    # The template bundle's likelihood is much narrower than a trained autoencoder's (raw pixel
    # correlation), which limits the 6D filters more than the Rao-Blackwellised one. Measured,
    # medians over the last 8 frames for seeds 0 / 1 / 2 (ADD in diameters, rotation in deg):
    # CH-PF RGB 0.55 / 0.45 / 0.60, 136 / 94 / 156 (with blind candidates it finds the box's
    # place, ADD-S 0.12 / 0.07 / 0.08, but not which way it is turned: no bound on ADD or the
    # rotation); RGB-D 0.20 / 0.54 / 0.15, 34 / 122 / 31 (seed 1 turned); informed 0.22 / 0.16 /
    # 0.19, 45 / 34 / 39; PoseRBPF 0.103 / 0.103 / 0.107, 17.2 / 15.9 / 15.9. Seed 0 is run.
    [
        ("chpf", "rgb", 0.15, None, None, PAPER),
        ("chpf", "rgbd", 0.15, 0.3, 50.0, PAPER),
        ("chpf", "rgb", 0.15, 0.3, 60.0, None),
        ("poserbpf", "rgb", 0.1, 0.15, 25.0, PAPER),
    ],
)
def test_tracker_reaches_a_small_adds_on_an_unoccluded_sequence(
    bundle, rendered_sequence, method, modality, max_adds, max_add, max_deg, config
):
    tracker = Tracker.from_bundle(bundle, method=method, modality=modality, seed=0, config=config)
    informed = config is None  # the default phi_cand is informed, the paper's blind
    assert isinstance(tracker.candidates.rotations, CodebookRotations) == informed
    errs, res = _track(tracker, rendered_sequence, modality)
    med = np.median(errs[-8:], axis=0)  # ADD-S (d), ADD (d), rotation (deg)
    assert med[0] < max_adds, (method, modality, errs)
    if max_add is not None:
        assert med[1] < max_add and med[2] < max_deg, (method, modality, med)
    r = res[-1]
    assert r.ok and r.R.shape == (3, 3) and r.t.shape == (3,)
    assert np.isfinite(r.alpha) and np.isfinite(r.sum_L) and np.isfinite(r.ess)
    assert np.isfinite(r.sum_C) == (method == "chpf")
    assert r.stage_ms["total"] > 0


def test_tracker_same_seed_same_poses_and_reset(bundle, rendered_sequence):
    def poses(tracker):
        _, res = _track(tracker, rendered_sequence, frames=range(6))
        return np.stack([np.concatenate([r.R.ravel(), r.t]) for r in res])

    a = poses(Tracker.from_bundle(bundle, method="chpf", seed=5))
    tr = Tracker.from_bundle(bundle, method="chpf", seed=5)
    np.testing.assert_array_equal(a, poses(tr))
    tr.reset()
    np.testing.assert_array_equal(a, poses(tr))  # reset restarts the same random stream
    tr.reset(seed=6)
    assert not np.allclose(a, poses(tr))


def test_tracker_rejects_bad_input(bundle, rendered_sequence, tmp_path):
    seq = rendered_sequence
    tr = Tracker.from_bundle(bundle, method="chpf")
    with pytest.raises(ImageSizeError):  # principal point outside the 320x240 image
        tr.step(seq.rgb[0], K=np.array([[500.0, 0, 400], [0, 500, 300], [0, 0, 1]]), box=None)
    # the K of a 640x480 camera on the 320x240 image: its principal point (319.5, 239.5) still
    # falls inside, and the pose came out 0.8 m off before the size was checked against K
    K_vga = np.array([[600.0, 0, 319.5], [0, 600, 239.5], [0, 0, 1]])
    with pytest.raises(ImageSizeError, match=r"image is 320x240 .* implies about 640x480"):
        tr.step(seq.rgb[0], K=K_vga, box=seq.box(0))
    with pytest.raises(ImageSizeError):
        tr.step(seq.rgb[0], depth=np.zeros((10, 10), np.float32), K=seq.K)
    with pytest.raises(ImageSizeError):
        tr.step(seq.rgb[0][..., 0], K=seq.K)
    with pytest.raises(BundleError):
        Tracker.from_bundle(bundle, runtime={"crop_size": 64})
    with pytest.raises(BundleError):
        Tracker.from_bundle(tmp_path / "missing")
    with pytest.raises(ConfigError):
        Tracker.from_bundle(bundle, method="bogus")
    with pytest.raises(ConfigError):
        Tracker.from_bundle(bundle, chpf={"c_mode": "depth"}, modality="rgb")
    with pytest.raises(ConfigError):
        Tracker.from_bundle(bundle, no_such_option=1)
    with pytest.raises(ConfigError, match=r"expected a TrackConfig, a dict of sections .* list"):
        Tracker(bundle, config=[("filter", {"n_particles": 7})])
    with pytest.raises(ConfigError, match=r"srl\.beta"):  # a key of the former flat form
        Tracker.from_bundle(bundle, srl_beta=0.5)


def test_tracker_takes_a_nested_dict_or_a_yaml_file_as_config(bundle):
    """Tracker(bundle, config=dict) used to fail with AttributeError."""
    tr = Tracker(bundle, method="srl", config={"srl": {"beta": 0.45}, "filter": {"n_particles": 7}})
    assert tr.filter.strategy.beta == 0.45 and tr.config.filter.n_particles == 7
    tr = Tracker(bundle, method="chpf", config=PAPER)
    assert tr.candidates.rotations is None and tr.filter.strategy.config.sums == "paper"
    with pytest.raises(ConfigError, match=r"unknown key srl\.betta"):
        Tracker(bundle, method="srl", config={"srl": {"betta": 0.5}})


def test_tracker_survives_missing_boxes_and_depth_holes(bundle, rendered_sequence):
    seq = rendered_sequence
    tr = Tracker.from_bundle(bundle, method="chpf", modality="rgbd", chpf={"c_mode": "both"})
    assert not tr.step(seq.rgb[0], depth=seq.depth[0], K=seq.K, box=None).ok
    for i in range(1, 8):
        depth = seq.depth[i].copy()
        depth[:, :160] = 0.0  # half the image has no depth
        box = None if i in (4, 5) else seq.box(i)
        r = tr.step(seq.rgb[i], depth=depth, K=seq.K, box=box)
        assert r.ok and np.all(np.isfinite(r.t)) and r.region is None
        assert r.weighed == (box is not None)  # boxes came after the first: a miss predicts


@pytest.mark.parametrize("method", ["chpf", "srl", "augmcl", "annealing", "e2e", "poserbpf++"])
def test_non_finite_depth_is_missing_depth(bundle, rendered_sequence, method):
    """+inf, -inf, NaN and negative depth (sensor markers) are holes: the poses equal those of
    the same run with 0 there (before: a cKDTree traceback for the 6D filters, NaN for the
    RBPFs)."""
    seq = rendered_sequence
    marked, holes = [], []
    for i in range(4):
        d = seq.depth[i].copy()
        d[:, ::4], d[::5, :], d[::7, ::3], d[1::9, :] = np.inf, np.nan, -np.inf, -0.5
        marked.append(d)
        holes.append(np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32))

    def poses(depths):
        tr = Tracker.from_bundle(bundle, method=method, modality="rgbd", seed=3)
        res = [tr.step(seq.rgb[i], depth=d, K=seq.K, box=seq.box(i)) for i, d in enumerate(depths)]
        return np.stack([np.concatenate([r.R.ravel(), r.t]) for r in res])

    got = poses(marked)
    assert np.all(np.isfinite(got))
    np.testing.assert_array_equal(got, poses(holes))


def _shipped_bundle() -> Bundle:
    from chpf.tracking.demo import shipped_bundle

    return Bundle.load(shipped_bundle())


def _can_passes_in_front(sequence_renderer, bundle: Bundle, frames: int, shown: slice):
    """The bundle's object at 3 diameters with a can passing in front (``frames`` frames), and
    the visible fraction of the object over the ``shown`` frames (its mask against a 21-frame
    sequence without the can; ``shown`` within its frames)."""
    z = 3.0 * bundle.obj_info.diameter
    seq = sequence_renderer(frames, name=bundle.obj_info.name, z=z, occluder="can")
    alone = sequence_renderer(21, name=bundle.obj_info.name, z=z)
    visible = seq.mask[shown].sum(axis=(1, 2)) / alone.mask[shown].sum(axis=(1, 2))
    return seq, visible


def test_shipped_bundle_likelihoods_rank_the_true_pose(sequence_renderer):
    """The trained L peaks at the true pose and C calls it aligned; C calls misaligned a pose
    shifted by a third of the diameter (within the training's crop jitter, ~0.04 diameters, it
    judges the orientation) and poses turned 45 deg about any axis."""
    from chpf.geometry import axis_angle_to_matrix, random_rotations
    from chpf.tracking.types import Frame

    bundle = _shipped_bundle()
    seq = sequence_renderer(1, name=bundle.obj_info.name, z=3.0 * bundle.obj_info.diameter)
    lik = Tracker.from_bundle(bundle, method="chpf").likelihood
    frame = Frame(rgb=seq.rgb[0], depth=None, K=seq.K, box=seq.box(0))
    R0, t0 = seq.R[0], seq.t[0]
    shifts = np.array([[0, 0, 0], [-0.02, 0, 0], [-0.1, 0.02, 0]])
    s = lik.score(frame, np.repeat(R0[None], 3, 0), t0 + shifts)
    assert s.L[0] > s.L[1] > s.L[2], s.L
    assert s.C[0] < 0.1 < 0.5 < s.C[2], s.C
    turned = axis_angle_to_matrix(np.radians(45.0) * np.eye(3)) @ R0
    assert np.all(lik.score(frame, turned, np.repeat(t0[None], 3, 0)).C > 0.5)
    n = 200
    rots = random_rotations(n, np.random.default_rng(0))
    rand = lik.score(frame, rots, np.repeat(t0[None], n, 0))
    assert s.L[0] > rand.L.max() and s.C[0] < np.percentile(rand.C, 5)


def test_orientation_search_moves_particles_towards_the_view_in_the_crop(sequence_renderer):
    """The shipped bundle, particles at the true translation turned 10 deg off: the search over
    12 grid neighbours scores each particle at least as well as without it (its own entry is
    among them), moves them closer to the true orientation on average, keeps each particle's
    offset from the grid (the move is a product of grid rotations) and leaves translations
    alone; without the search the scored orientations are the given ones (Scores.R None)."""
    bundle = _shipped_bundle()
    seq = sequence_renderer(1, name=bundle.obj_info.name, z=3.0 * bundle.obj_info.diameter)
    frame = Frame(rgb=seq.rgb[0], depth=None, K=seq.K, box=seq.box(0))
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R = axis_angle_to_matrix(np.radians(10.0) * axes) @ seq.R[0]
    t = np.repeat(seq.t[:1], 40, 0)
    plain = BundleLikelihood(bundle).score(frame, R, t)
    searched = BundleLikelihood(bundle, refine_neighbours=12).score(frame, R, t)
    assert plain.R is None and searched.R is not None
    assert np.all(searched.L >= plain.L - 1e-6) and searched.L.mean() > plain.L.mean()
    before = np.degrees(geodesic_angle(R, seq.R[0])).mean()
    after = np.degrees(geodesic_angle(searched.R, seq.R[0])).mean()
    assert after < before, (before, after)


def test_the_classifier_finds_the_orientation_in_a_misplaced_box_crop(sequence_renderer):
    """phi_cand's orientations at detection boxes 0.12 of a side off the object (the shipped
    bundle, 8 frames, 4 shifts each): ranked by the classifier among the cosine's 1024 best
    entries (``candidates.rerank``, the default) they come within 20 deg of the truth more than
    twice as often as by the cosine alone (measured: 37 % of them against 14 %), and some do on
    more boxes (29 of 32 against 19)."""
    bundle = _shipped_bundle()
    seq = sequence_renderer(8, name=bundle.obj_info.name, z=3.0 * bundle.obj_info.diameter)
    share = {}
    for rerank in (0, 1024):
        tracker = Tracker.from_bundle(
            bundle, method="chpf", config={"candidates": {"rerank": rerank}}
        )
        rng = np.random.default_rng(0)
        near = []
        for i in range(8):
            x, y, w, h = seq.box(i)
            for dx, dy in ((0.12, 0.0), (-0.12, 0.0), (0.0, 0.12), (0.0, -0.12)):
                frame = Frame(seq.rgb[i], None, seq.K, (x + dx * w, y + dy * h, w, h))
                R, _ = tracker.candidates.sample(200, frame, rng)
                near.append(
                    (geodesic_angle(R, np.broadcast_to(seq.R[i], R.shape)) < np.radians(20)).mean()
                )
        share[rerank] = np.array(near)
    assert share[1024].mean() > max(2.0 * share[0].mean(), 0.3), share
    assert (share[1024] > 0).mean() >= 0.8 > (share[0] > 0).mean(), share


def test_anchored_boxes_hold_the_box_flush_with_its_sides_or_centred():
    """A 30 x 40 px box: with side 1 the 40 px squares flush left or right (its height already
    spans them; the centred one is the box's own crop, left out); with side 1.5 the nine 60 px
    squares; each holds it. A square box at side 1 has no other."""
    assert anchored_boxes((5.0, 5.0, 20.0, 20.0), (1.0,)).shape == (0, 4)
    boxes = anchored_boxes((10.0, 20.0, 30.0, 40.0), (1.0, 1.5))
    expected = {(x0, 20.0, 40.0, 40.0) for x0 in (10.0, 0.0)} | {
        (x0, y0, 60.0, 60.0) for x0 in (10.0, -20.0, -5.0) for y0 in (20.0, 0.0, 10.0)
    }
    assert {tuple(float(v) for v in b) for b in boxes} == expected
    assert np.all(boxes[:, 0] <= 10.0) and np.all(boxes[:, 0] + boxes[:, 2] >= 40.0)
    assert np.all(boxes[:, 1] <= 20.0) and np.all(boxes[:, 1] + boxes[:, 3] >= 60.0)


def test_the_reference_reads_the_whole_objects_box_too(sequence_renderer):
    """``reference_anchors``: a can passes in front of the box (the shipped bundle, the visible
    part's box as the detection). The box crop's best entry alone is a poor yardstick: its C
    comes out far above C at the true pose on some frames (measured: 0.94 and 0.99 against 0.00
    at 69 % and 91 % visible). Read in the anchored squares as well, C_ref is never above the
    box crop's and within 0.1 of C at the true pose on every frame (measured: 0.06 at most).
    A search region's box (no detection) is the model's projection, not a visible part: there
    the reference is the box crop's alone."""
    bundle = _shipped_bundle()
    seq, _ = _can_passes_in_front(sequence_renderer, bundle, 16, slice(0, 16))
    plain = BundleLikelihood(bundle, reference="box")
    anchored = BundleLikelihood(bundle, reference="box", reference_anchors=(1.0, 1.4))
    gaps = []
    for i in range(16):
        frame = Frame(seq.rgb[i], None, seq.K, seq.box(i))
        truth = plain.score(frame, seq.R[i : i + 1], seq.t[i : i + 1])
        (L_box, C_box), (L_anc, C_anc) = truth.reference, anchored.frame_reference(frame)
        assert L_anc == L_box and C_anc <= C_box
        gaps.append((C_box - truth.C[0], C_anc - truth.C[0]))
        region = Region(box=seq.box(i), area=seq.box(i), window=seq.box(i))
        searched = Frame(seq.rgb[i], None, seq.K, None, region)
        assert anchored.frame_reference(searched) == plain.frame_reference(searched)
    gaps = np.array(gaps)
    assert gaps[:, 0].max() > 0.5 and gaps[:, 1].max() < 0.1, gaps


@pytest.mark.parametrize(
    ("method", "config", "max_adds", "max_add", "max_deg"),
    [
        ("e2e", PAPER, 0.1, 0.13, 10.0),
        ("poserbpf", PAPER, 0.2, 0.4, 20.0),
        ("chpf", None, 0.2, 0.4, 12.0),
        ("chrbpf", None, 0.2, 0.4, 20.0),
    ],
)
def test_shipped_bundle_tracks_an_unoccluded_sequence(
    sequence_renderer, method, config, max_adds, max_add, max_deg
):
    """Starting from the detection boxes alone, MCL + E2E, PoseRBPF (the paper's setting), CH-PF
    and CH-RBPF (the default; with the paper's uniform phi_cand CH-PF stays a 6D random search,
    see the README) track the pose with the trained networks: the medians over frames 10-29 of
    seeds 0-2 of ADD-S and ADD (diameters) and of the rotation error (deg) are below the bounds
    (measured: E2E 0.049, 0.087, 6.4 deg; PoseRBPF 0.143, 0.272, 13.5 deg, whose seeds range
    from 0.09 to 0.32 in ADD-S; CH-PF 0.171, 0.330, 8.2 deg, whose seeds range from 0.06 to
    0.19 in ADD-S: with seed 1 the belief drifts 0.45 diameter towards the camera with alpha
    near 0, a depth error neither network sees well (bundle_likelihood, item 6); CH-RBPF
    0.110, 0.211, 11.7 deg)."""
    bundle = _shipped_bundle()
    seq = sequence_renderer(30, name=bundle.obj_info.name, z=3.0 * bundle.obj_info.diameter)
    errs = []
    for seed in (0, 1, 2):
        tracker = Tracker.from_bundle(bundle, method=method, config=config, seed=seed)
        errs.append(_track(tracker, seq)[0][10:])
    med = np.median(np.concatenate(errs), axis=0)
    assert med[0] < max_adds and med[1] < max_add and med[2] < max_deg, (method, med)


@pytest.mark.parametrize(
    ("method", "config", "max_add", "max_deg"),
    [("e2e", PAPER, 0.12, 10.0), ("poserbpf", PAPER, 0.45, 18.0), ("chpf", None, 0.35, 12.0)],
)
def test_shipped_bundle_tracks_through_an_occluder(
    sequence_renderer, method, config, max_add, max_deg
):
    """A can passes in front of the box (frames 8-20 show 54-97 % of it; the box is the
    visible part's): the medians over those frames of seeds 0-2 of ADD (diameters) and of the
    rotation error (deg) stay below the bounds (measured: E2E 0.078, 5.6 deg; PoseRBPF 0.295,
    10.9 deg, the paper's setting; CH-PF 0.286, 8.3 deg, the default)."""
    bundle = _shipped_bundle()
    seq, visible = _can_passes_in_front(sequence_renderer, bundle, 30, slice(8, 21))
    assert visible.min() < 0.6 and visible.max() < 1.0  # the can hides a good part of the box
    errs = []
    for seed in (0, 1, 2):
        tracker = Tracker.from_bundle(bundle, method=method, config=config, seed=seed)
        errs.append(_track(tracker, seq, frames=range(21))[0][8:])
    med = np.median(np.concatenate(errs), axis=0)
    assert med[1] < max_add and med[2] < max_deg, (method, med)


@pytest.mark.parametrize("method", ["chpf", "srl"])
def test_shipped_bundle_rgbd_is_at_least_as_accurate_as_rgb(sequence_renderer, method):
    """With the paper's phi_cand ((u, v) anywhere in the box, also on the background) and a wall
    2 m behind the box in the depth image, RGB-D is at least as accurate as RGB: medians over
    frames 10-29 of seeds 0-2 of ADD-S and ADD. Measured (ADD-S, ADD in diameters): CH-PF RGB
    0.132, 0.382, RGB-D 0.104, 0.334; SRL RGB 0.124, 0.373, RGB-D 0.114, 0.357. Before,
    candidates took the wall's depth and L was multiplied by L_depth: RGB-D 1.17 and 1.30
    ADD-S, the estimate 1.4-1.7 diameters off."""
    bundle = _shipped_bundle()
    seq = sequence_renderer(30, name=bundle.obj_info.name, z=3.0 * bundle.obj_info.diameter)
    med = {}
    for modality in ("rgb", "rgbd"):
        errs = []
        for seed in (0, 1, 2):
            tracker = Tracker.from_bundle(
                bundle, method=method, modality=modality, seed=seed, config=PAPER
            )
            errs.append(_track(tracker, seq, modality, wall=2.0)[0][10:])
        med[modality] = np.median(np.concatenate(errs), axis=0)
    assert np.all(med["rgbd"][:2] <= med["rgb"][:2]), (method, med)


def test_shipped_bundle_c_calls_an_occluded_but_aligned_crop_aligned(sequence_renderer):
    """A can passes in front of the box (frames 8-13 show 54-85 % of it): at the true pose the
    learned C stays below 0.5 on every one of them, occlusion is no evidence of misalignment
    (measured: 0.015 at most, at 64 % visible), while the same poses turned 45 deg are called
    misaligned (0.956 at least). The poses are scored as given (no orientation search)."""
    bundle = _shipped_bundle()
    seq, visible = _can_passes_in_front(sequence_renderer, bundle, 21, slice(8, 14))
    assert visible.min() < 0.6 and visible.max() < 0.9  # the can hides a good part of the box
    as_given = {"likelihood": {"refine_neighbours": 0}}
    lik = Tracker.from_bundle(bundle, method="chpf", config=as_given).likelihood
    turn = axis_angle_to_matrix(np.radians(45.0) * np.array([0.0, 1.0, 0.0]))
    C = []
    for i in range(8, 14):
        frame = Frame(rgb=seq.rgb[i], depth=None, K=seq.K, box=seq.box(i))
        R = np.stack([seq.R[i], turn @ seq.R[i]])
        C.append(lik.score(frame, R, np.repeat(seq.t[i][None], 2, 0)).C)
    C = np.array(C)
    assert C[:, 0].max() < 0.5 and C[:, 1].min() > 0.9, C.round(3)


def test_shipped_bundle_chpf_alpha_rises_after_a_forced_collapse_and_the_estimate_recovers(
    sequence_renderer,
):
    """Default config, seeds 0-2: CH-PF tracks with a low alpha, every particle is then put on
    one wrong pose (90 deg off, 0.3 d aside) at frame 30: alpha rises above 0.8, the
    orientation comes back, the position comes back onto the object's ray and alpha falls
    again. Measured, seeds 0 / 1 / 2 (the default, with the silhouette's C): over frames 20-29
    ADD-S 0.04 / 0.08 / 0.07 d, alpha 0.15 / 0.18 / 0.17; alpha 0.95 / 0.91 / 0.92 at the
    collapse and 0.20 / 0.22 / 0.25 over frames 50-59; after frame 40 median rotation error
    1.8 / 3.0 / 2.6 deg and ADD-S 0.01 / 0.05 / 0.07 d. (Before the silhouette: alpha about
    0.01 while tracking, ADD-S 0.05 / 0.10 / 0.10 d after frame 40.) On this clean render the
    outline's contrast at the true pose is 0.84-1.0 while the set's particles, spread over 5-7 %
    in depth by the motion model, reach 0.4-0.6: the set fits the frame worse than the box's
    own estimate, and alpha says so (the bench's tracked frames: 0.11). So the bounds are the
    issue's 0.25 while tracking and 0.3 once settled again (the mean over the seeds: on an
    AVX2-only CPU, whose float32 kernels round differently, the runs diverge and frames 50-59
    read alpha 0.33 / 0.26 / 0.25, ADD-S after frame 40 0.14 / 0.08 / 0.07 d); before the
    collapse the ray (the true centre within 0.1 d of the estimated ray) and the depth (within
    20 %), after it the ray's ADD-S bound per seed (0.25 d) and 0.12 d for the median over the
    seeds."""
    bundle = _shipped_bundle()
    d = bundle.obj_info.diameter
    seq = sequence_renderer(60, name=bundle.obj_info.name, z=3.0 * d)
    recovered, settled = [], []
    for seed in (0, 1, 2):
        tracker = Tracker.from_bundle(bundle, method="chpf", seed=seed)
        errs, res = _track(tracker, seq, collapse_at=30)
        alphas = np.array([r.alpha for r in res])
        adds_errs, _, rot_err = errs.T
        t_est = np.array([r.t for r in res[20:30]])
        ray = t_est / np.linalg.norm(t_est, axis=1, keepdims=True)
        off_ray = np.linalg.norm(np.cross(seq.t[20:30], ray), axis=1) / d
        depth = t_est[:, 2] / seq.t[20:30, 2]
        assert np.median(off_ray) < 0.1 and 0.8 < np.median(depth) < 1.2, seed  # tracking
        assert alphas[20:30].mean() < 0.25
        assert rot_err[30] > 45.0 and alphas[30] > 0.8  # collapsed: doubt, reinvigoration
        # recovered: the orientation is back (the collapse turned it 90 deg), the position too
        assert np.median(rot_err[40:]) < 10.0 and np.median(adds_errs[40:]) < 0.25, seed
        settled.append(alphas[50:].mean())
        recovered.append(np.median(adds_errs[40:]))
    assert np.median(recovered) < 0.12, recovered
    assert np.mean(settled) < 0.3, settled  # settled again


def test_boxes_as_text_are_refused_and_invalid_boxes_warned_once(bundle, rendered_sequence):
    """A box given as a string is a one-line InputError (was: a numpy ValueError); a box with
    zero or negative size, a NaN or three numbers makes the frame one without a box (searched
    around the estimate) with one warning per tracker naming the first such frame (was:
    silently "no box")."""
    from chpf.errors import InputError
    from chpf.tracking.warn import InvalidBoxWarning

    seq = rendered_sequence
    tr = Tracker.from_bundle(bundle, method="chpf")
    for text in ("10,20,30,40", b"1234", {"x": 1}):
        with pytest.raises(InputError, match=r"box must be 4 numbers \(x, y, w, h\)"):
            tr.step(seq.rgb[0], K=seq.K, box=text)
    assert tr.step(seq.rgb[0], K=seq.K, box=seq.box(0)).weighed  # frame 0
    bad = [(1, 2, 0, 4), (1, 2, -3, 4), (np.nan, 1, 2, 3), (1, 2, 3)]
    with pytest.warns(InvalidBoxWarning) as rec:
        for i, box in enumerate(bad, start=1):
            assert tr.step(seq.rgb[i], K=seq.K, box=box).region is not None
    assert len(rec) == 1
    assert "frame 1: invalid box (1, 2, 0, 4)" in str(rec[0].message)
    tr.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per tracker, also after a reset
        assert not tr.step(seq.rgb[0], K=seq.K, box=(0, 0, 0, 0)).ok


def test_poses_come_out_in_the_mesh_files_frame(template_bundle, rendered_sequence):
    """A bundle made from a mesh whose origin is off its centre tracks the centred object
    (ObjectInfo.file_offset) and reports each pose in the file's frame: the same rotation, and
    t - R file_offset, so that R p + t places the file's points p where the tracked ones are."""
    seq = rendered_sequence
    offset = np.array([0.01, -0.02, 0.05])
    plain = Bundle.load(template_bundle)
    shifted = Bundle.load(template_bundle)
    shifted.obj_info = replace(shifted.obj_info, file_offset=offset)
    runs = [Tracker(b, method="chpf", seed=3) for b in (plain, shifted)]
    for i in range(3):
        a, b = (tr.step(seq.rgb[i], K=seq.K, box=seq.box(i)) for tr in runs)
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_allclose(b.t, a.t - a.R @ offset, atol=1e-12)
        p = np.array([0.03, 0.0, -0.01])  # a point of the centred object, and of the file's
        np.testing.assert_allclose(b.R @ (p + offset) + b.t, a.R @ p + a.t, atol=1e-12)
