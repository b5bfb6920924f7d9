"""The candidate distribution phi_cand: boxes, depth ranges, depth holes."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.geometry import project_points
from chpf.tracking.candidates import CandidateSampler, corners, inner_margins, valid_box
from chpf.tracking.types import Frame

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
RGB = np.zeros((480, 640, 3), np.uint8)
BOX = (100.0, 50.0, 80.0, 60.0)


def in_box(uv, box, tol=1e-6):
    return (
        (uv[:, 0] >= box[0] - tol)
        & (uv[:, 0] <= box[0] + box[2] + tol)
        & (uv[:, 1] >= box[1] - tol)
        & (uv[:, 1] <= box[1] + box[3] + tol)
    )


def test_inner_margins_measure_each_side_and_broadcast_over_boxes():
    """Left, top, right, bottom distances of the inner box inside the outer one (negative
    where it sticks out), for one box or a stack of them against one."""
    outer = corners(BOX)  # x 100-180, y 50-110
    assert list(outer) == [100.0, 50.0, 180.0, 110.0]
    inner = np.array([[110.0, 55.0, 170.0, 100.0], [90.0, 60.0, 190.0, 120.0]])
    np.testing.assert_allclose(inner_margins(inner[0], outer), [10.0, 5.0, 10.0, 10.0])
    np.testing.assert_allclose(
        inner_margins(inner, outer), [[10.0, 5.0, 10.0, 10.0], [-10.0, 10.0, -10.0, -10.0]]
    )


def test_rgb_candidates_project_into_the_box_with_z_in_range():
    R, t = CandidateSampler(z_range=(0.5, 1.5)).sample(
        2000, Frame(RGB, None, K, BOX), np.random.default_rng(0)
    )
    assert R.shape == (2000, 3, 3) and t.shape == (2000, 3)
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), eye, atol=1e-9)
    assert np.all(in_box(project_points(t, K), BOX))
    assert t[:, 2].min() >= 0.5 and t[:, 2].max() <= 1.5 and np.ptp(t[:, 2]) > 0.9
    # orientations are uniform: the mean rotation matrix is close to 0
    assert np.abs(R.mean(axis=0)).max() < 0.06


def test_uv_fraction_keeps_candidates_in_the_centre_of_the_box():
    frame = Frame(RGB, None, K, BOX)
    _, t = CandidateSampler(z_range=(0.5, 1.5), uv_fraction=0.25).sample(
        2000, frame, np.random.default_rng(0)
    )
    centre = (BOX[0] + 0.375 * BOX[2], BOX[1] + 0.375 * BOX[3], 0.25 * BOX[2], 0.25 * BOX[3])
    uv = project_points(t, K)
    assert np.all(in_box(uv, centre))
    # ... and fill that central quarter, as the whole box does with the default 1.0
    assert np.ptp(uv[:, 0]) > 0.9 * centre[2] and np.ptp(uv[:, 1]) > 0.9 * centre[3]
    _, t = CandidateSampler(z_range=(0.5, 1.5)).sample(2000, frame, np.random.default_rng(0))
    assert np.ptp(project_points(t, K)[:, 0]) > 0.9 * BOX[2]


def test_rgb_z_from_the_box_scale():
    s = CandidateSampler(box_extent=0.1, z_box_factors=(0.9, 1.1))
    _, t = s.sample(500, Frame(RGB, None, K, BOX), np.random.default_rng(0))
    z_box = 500 * 0.1 / 80.0
    assert t[:, 2].min() >= 0.9 * z_box - 1e-9 and t[:, 2].max() <= 1.1 * z_box + 1e-9


def test_rgbd_candidates_follow_the_measured_depth_and_survive_holes():
    depth = np.zeros((480, 640), np.float32)
    depth[50:110, 100:180] = 0.7
    rng = np.random.default_rng(0)
    depth[rng.random(depth.shape) < 0.5] = 0.0  # half the pixels are holes
    s = CandidateSampler(z_range=(2.0, 3.0), depth_offset=(0.0, 0.02))
    _, t = s.sample(500, Frame(RGB, depth, K, BOX), rng)
    assert np.all((t[:, 2] >= 0.7 - 1e-6) & (t[:, 2] <= 0.72 + 1e-6))
    # a box with no valid depth at all falls back to the RGB rule
    _, t = s.sample(50, Frame(RGB, np.zeros_like(depth), K, BOX), rng)
    assert np.all((t[:, 2] >= 2.0) & (t[:, 2] <= 3.0))
    # use_depth=False ignores the depth image
    _, t = CandidateSampler(z_range=(2.0, 3.0), use_depth=False).sample(
        20, Frame(RGB, depth, K, BOX), rng
    )
    assert np.all(t[:, 2] >= 2.0)


def test_rgbd_candidates_skip_the_background_seen_past_the_object():
    """Depth beyond the box scale's far end is the background around the object (a box 80 px
    wide at f 500 holds an object of 0.112 m extent at z_box 0.7 m): those pixels count as
    holes, so no candidate lands on the wall 3 m away (before: half of them did)."""
    depth = np.full((480, 640), 3.0, np.float32)  # a wall
    depth[65:95, 120:160] = 0.7  # the object, the central part of the box
    s = CandidateSampler(box_extent=0.112, depth_offset=(0.0, 0.02))
    _, t = s.sample(500, Frame(RGB, depth, K, BOX), np.random.default_rng(0))
    assert np.all((t[:, 2] >= 0.7 - 1e-6) & (t[:, 2] <= 0.72 + 1e-6))
    # nearer than the box scale is kept (an occluder, or an object whose box is partly hidden)
    depth[:] = 0.4
    _, t = s.sample(50, Frame(RGB, depth, K, BOX), np.random.default_rng(0))
    assert np.all(t[:, 2] <= 0.42 + 1e-6)


def test_boxes_partly_outside_the_image():
    depth = np.full((480, 640), 0.9, np.float32)
    box = (600.0, 450.0, 100.0, 100.0)
    _, t = CandidateSampler(depth_offset=(0.0, 0.0)).sample(
        100, Frame(RGB, depth, K, box), np.random.default_rng(0)
    )
    np.testing.assert_allclose(t[:, 2], 0.9, atol=1e-6)
    assert np.all(in_box(project_points(t, K), box))


def test_valid_box():
    assert valid_box((1, 2, 3, 4)) == (1.0, 2.0, 3.0, 4.0)
    for bad in (None, (1, 2, 0, 4), (1, 2, 3, -1), (np.nan, 0, 1, 1), (1, 2, 3)):
        assert valid_box(bad) is None
    with pytest.raises(ValueError):
        CandidateSampler().sample(3, Frame(RGB, None, K, None), np.random.default_rng(0))


class _FixedScorer:
    """Box-centre cosines that single out entries 3 (best) and 7 (second) of a small grid; the
    classifier finds entry 7 aligned (C 0.05), entry 20 as well (but its cosine is the least)
    and every other entry misaligned (C 0.9)."""

    def __init__(self):
        from chpf.geometry import RotationGrid

        self.grid = RotationGrid.uniform(64)
        self.cos = np.linspace(0.5, 0.0, 64)
        self.cos[3], self.cos[7], self.cos[20] = 0.9, 0.85, -0.5
        self.C = np.full(64, 0.9)
        self.C[7] = self.C[20] = 0.05

    def box_centre_cosines(self, frame):
        return None if frame.box is None else (self.cos, np.array([0.0, 0.0, 1.0]))

    def box_centre_misalignment(self, frame, t0, idx):
        return self.C[idx]


def test_codebook_rotations_follow_the_box_crop_look_up():
    from chpf.geometry import allocentric_to_egocentric, egocentric_to_allocentric, geodesic_angle
    from chpf.tracking.codebook_candidates import CodebookRotations

    scorer = _FixedScorer()
    source = CodebookRotations(scorer, temperature=0.05, uniform_share=0.25, rerank=0)
    p = source.probabilities(scorer.cos)
    assert p.sum() == pytest.approx(1.0) and p[3] / p[7] == pytest.approx(np.exp(1.0))
    assert p[3] / p[0] == pytest.approx(np.exp(8.0))
    sampler = CandidateSampler(z_range=(0.5, 1.5), rotations=source)
    R, t = sampler.sample(400, Frame(RGB, None, K, BOX), np.random.default_rng(0))
    assert np.all(in_box(project_points(t, K), BOX))  # translations as with uniform rotations
    R_allo = egocentric_to_allocentric(R, t)  # the entries are allocentric: through each ray
    d3 = geodesic_angle(R_allo, np.broadcast_to(scorer.grid.rotations[3], R.shape))
    d7 = geodesic_angle(R_allo, np.broadcast_to(scorer.grid.rotations[7], R.shape))
    from_codebook = (d3 < 1e-6) | (d7 < 1e-6)
    assert from_codebook[:300].all() and from_codebook[300:].mean() < 0.1  # 25 % uniform
    assert 0.6 < (d3[:300] < 1e-6).mean() < 0.85  # e / (1 + e) = 0.73 of them are entry 3
    np.testing.assert_allclose(
        R[0], allocentric_to_egocentric(scorer.grid.rotations[3 if d3[0] < 1e-6 else 7], t[0])
    )
    # without a box the source falls back to uniform orientations
    R_none = source.sample(
        200, Frame(RGB, None, K, None), t[:1].repeat(200, 0), np.random.default_rng(1)
    )
    assert np.abs(R_none.mean(axis=0)).max() < 0.15


def test_the_classifier_ranks_the_best_cosines_entries():
    """rerank M: among the M entries of best cosine, the classifier's C decides (entry 7 over
    the cosine's best, 3); an entry outside them (20) is never drawn, however aligned."""
    from chpf.geometry import egocentric_to_allocentric, geodesic_angle
    from chpf.tracking.codebook_candidates import CodebookRotations

    scorer = _FixedScorer()
    source = CodebookRotations(scorer, uniform_share=0.0, rerank=16, c_temperature=0.05)
    frame = Frame(RGB, None, K, BOX)
    idx, p = source.entries(frame, scorer.cos, np.zeros(3))
    assert sorted(idx) == sorted(np.argsort(-scorer.cos)[:16]) and 20 not in idx
    assert p.sum() == pytest.approx(1.0)
    assert p[idx == 7][0] / p[idx == 3][0] == pytest.approx(np.exp(0.85 / 0.05))
    t = np.tile([0.0, 0.0, 1.0], (200, 1))
    R = source.sample(200, frame, t, np.random.default_rng(0))
    d7 = geodesic_angle(
        egocentric_to_allocentric(R, t), np.broadcast_to(scorer.grid.rotations[7], R.shape)
    )
    assert (d7 < 1e-6).all()


def test_codebook_rotations_refuse_bad_settings():
    from chpf.errors import ConfigError
    from chpf.tracking.codebook_candidates import CodebookRotations

    with pytest.raises(ConfigError):
        CodebookRotations(_FixedScorer(), temperature=0.0)
    with pytest.raises(ConfigError):
        CodebookRotations(_FixedScorer(), uniform_share=1.5)
    with pytest.raises(ConfigError):
        CodebookRotations(_FixedScorer(), rerank=-1)
    with pytest.raises(ConfigError):
        CodebookRotations(_FixedScorer(), c_temperature=0.0)


_K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
_BELIEF = (np.eye(3), np.array([0.0, 0.0, 1.0]))  # box_extent 0.2: 60 px square around (160, 120)


def _u(t: np.ndarray) -> np.ndarray:
    return _K[0, 0] * t[:, 0] / t[:, 2] + _K[0, 2]


def test_a_detection_inside_the_belief_box_is_read_as_its_visible_part():
    """occluded_rule "inside": a detection inside the belief's projected box and smaller by
    more than 10 % gives the belief's box (candidates at the believed place and scale); a
    detection as large as the belief, or elsewhere, stays the box; off, or on an RGB-D frame,
    the detection is always the box."""
    sampler = CandidateSampler(box_extent=0.2, occluded_box=True, occluded_rule="inside")
    bel = sampler.belief_box(_BELIEF[1], _K)
    assert bel == pytest.approx((130.0, 90.0, 60.0, 60.0))
    half = Frame(np.zeros((240, 320, 3), np.uint8), None, _K, (130.0, 100.0, 40.0, 50.0))
    assert sampler.box_for(half, _BELIEF) == pytest.approx(bel)
    whole = Frame(half.rgb, None, _K, (131.0, 91.0, 58.0, 58.0))
    elsewhere = Frame(half.rgb, None, _K, (10.0, 10.0, 30.0, 30.0))
    assert sampler.box_for(whole, _BELIEF) == whole.box
    assert sampler.box_for(elsewhere, _BELIEF) == elsewhere.box
    assert sampler.box_for(half, None) == half.box
    off = CandidateSampler(box_extent=0.2)
    assert off.box_for(half, _BELIEF) == half.box
    with_depth = Frame(half.rgb, np.ones((240, 320), np.float32), _K, half.box)
    assert sampler.box_for(with_depth, _BELIEF) == half.box  # RGB-D: z is measured
    _, ts = sampler.sample(200, half, np.random.default_rng(0), _BELIEF)
    u = _u(ts)
    assert u.min() > 130.0 and u.max() < 190.0 and u.mean() == pytest.approx(160.0, abs=3.0)
    poking_out = Frame(half.rgb, None, _K, (150.0, 80.0, 30.0, 30.0))  # 10 px above the belief
    assert sampler.box_for(poking_out, _BELIEF) == poking_out.box


def test_a_detection_overlapping_the_belief_box_places_the_object_around_it():
    """occluded_rule "around" (the default): a detection smaller than the belief's box by more
    than 10 % that overlaps it is the visible part of an object of the belief's size wherever
    that object holds it: the candidates' depth is the belief's, their centres lie where a
    square of the belief's side still holds the whole detection, even when the belief is off
    and the detection pokes out of its box (the "inside" rule drew such candidates from the
    detection's own box, twice too far away). A detection beside the belief's box stays the
    box."""
    sampler = CandidateSampler(box_extent=0.2, occluded_box=True, uv_fraction=0.3)
    assert sampler.occluded_rule == "around"
    poking_out = Frame(np.zeros((240, 320, 3), np.uint8), None, _K, (170.0, 80.0, 30.0, 30.0))
    assert sampler.box_for(poking_out, _BELIEF) == pytest.approx((155.0, 65.0, 60.0, 60.0))
    _, ts = sampler.sample(400, poking_out, np.random.default_rng(0), _BELIEF)
    assert ts[:, 2].mean() == pytest.approx(1.05, abs=0.04)  # z_box_factors (0.75, 1.35) x 1 m
    u = _u(ts)
    v = _K[1, 1] * ts[:, 1] / ts[:, 2] + _K[1, 2]
    # a 60 px square holds [170, 200] x [80, 110] when its centre is in [170, 200] x [80, 110]
    # (170 + 30 - 30 .. 170 + 30); the central 30 % of a detection's box adds 0.15 of the side
    assert u.min() > 170.0 - 9.5 and u.max() < 200.0 + 9.5
    assert v.min() > 80.0 - 9.5 and v.max() < 110.0 + 9.5
    assert np.ptp(u) > 30.0  # spread over the whole span, not only the detection's centre
    detection_only = CandidateSampler(box_extent=0.2, uv_fraction=0.3).sample(
        400, poking_out, np.random.default_rng(0), _BELIEF
    )[1]
    assert detection_only[:, 2].mean() == pytest.approx(2.1, abs=0.1)  # 30 px: z_box 2 m
    beside = Frame(poking_out.rgb, None, _K, (20.0, 20.0, 30.0, 30.0))
    assert sampler.box_for(beside, _BELIEF) == beside.box


def test_a_detection_well_inside_the_belief_box_on_every_side_says_the_belief_is_too_near():
    """occluded_rule "around": an occluder hides the object from one or two sides, so a
    visible part reaches one side of the object's box; a detection 10 px (a sixth of the side)
    inside the belief's 60 px box on all four sides is the whole object seen by a belief that
    is too near, and stays the box (the "inside" rule read it as the visible part and drew the
    candidates at the belief's too-near depth, which kept the set there)."""
    framed = Frame(np.zeros((240, 320, 3), np.uint8), None, _K, (140.0, 100.0, 40.0, 40.0))
    around = CandidateSampler(box_extent=0.2, occluded_box=True)
    assert around.box_for(framed, _BELIEF) == framed.box
    inside = CandidateSampler(box_extent=0.2, occluded_box=True, occluded_rule="inside")
    assert inside.box_for(framed, _BELIEF) == pytest.approx((130.0, 90.0, 60.0, 60.0))
    flush = Frame(framed.rgb, None, _K, (135.0, 92.0, 40.0, 40.0))  # 2 px from the top
    assert around.box_for(flush, _BELIEF) == pytest.approx((130.0, 90.0, 60.0, 60.0))
    # the belief's own outline (a thin object: 36 px wide at this pose) is what the detection
    # fills; the square of the median extent would call its belief too near
    thin = CandidateSampler(
        box_extent=0.2, occluded_box=True, outline_box=lambda R, t, K: (142.0, 95.0, 36.0, 50.0)
    )
    assert thin.box_for(framed, _BELIEF) == pytest.approx((130.0, 90.0, 60.0, 60.0))
