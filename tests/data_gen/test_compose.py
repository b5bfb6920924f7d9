"""Sample composition from the pools: labels, geometry of the crops, occlusion accounting."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.crops import CropSpec, crop_affines, extract_crops
from chpf.errors import ConfigError
from chpf.geometry import geodesic_angle, random_rotations
from chpf.objects import builtin_object
from data_gen.compose import Composer, ComposerContext, build_pools, depth_off
from data_gen.config import load_config
from data_gen.pool import window_intrinsics
from data_gen.rotations import grid_spacing_deg, symmetric_angle, symmetry_set


@pytest.fixture
def composer(pool_cache, tiny_sets):
    """``composer(kind="pairs", name="mug", *sets)`` -> (Composer, object) on tiny pools."""

    def make(kind="pairs", name="mug", *sets):
        cfg = load_config(None, [*tiny_sets, *sets])
        obj = builtin_object(name)
        spec = CropSpec.for_object(obj.diameter, cfg["crop"]["size"])
        setup = build_pools(ComposerContext(obj, spec, cfg, str(pool_cache), kind), progress=False)
        return Composer(setup), obj

    return make


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_labels_and_angles(composer):
    comp, _ = composer()
    out = comp.pairs(np.random.default_rng(0), 200)
    assert out["aligned"].sum() == 100
    spacing = grid_spacing_deg(comp.grid)["max"]
    pos, neg = out["aligned"] == 1, out["aligned"] == 0
    ang = np.degrees(
        geodesic_angle(out["obs_R_allo"].astype(float), out["cand_R_allo"].astype(float))
    )
    np.testing.assert_allclose(ang, out["angle_deg"], atol=1e-2)  # mug: no symmetry
    assert ang[pos].max() <= 10.0 + spacing + 1e-3
    assert ang[neg].min() >= 20.0
    # candidates are codebook entries, rendered in the codebook pool
    idx = comp.grid.nearest(out["cand_R_allo"].astype(float))
    np.testing.assert_array_equal(out["cand_rgb"], comp.cb.rgb[idx])
    # hard negatives exist (20-45 degrees before snapping)
    assert (ang[neg] < 60).sum() > 10


def test_flip_negatives_are_half_turns_about_an_object_axis(composer):
    comp, _ = composer(
        "pairs", "mug", "pairs.flip_negative_share=1.0", "pairs.hard_negative_share=0.0"
    )
    out = comp.pairs(np.random.default_rng(3), 120)
    neg = out["aligned"] == 0
    R_obs = out["obs_R_allo"][neg].astype(float)
    R_cand = out["cand_R_allo"][neg].astype(float)
    # the candidate is within perturbation + grid spacing of R_obs @ H for a half turn H about
    # x, y or z, and far from R_obs itself
    spacing = grid_spacing_deg(comp.grid)["max"]
    halves = [np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1])]
    off = np.min([np.degrees(geodesic_angle(R_obs @ H, R_cand)) for H in halves], axis=0)
    assert off.max() <= 10.0 + spacing + 1e-3
    assert out["angle_deg"][neg].min() >= 180.0 - 10.0 - spacing - 1e-3
    with pytest.raises(ConfigError, match="flip_negative_share"):
        load_config(None, ["pairs.flip_negative_share=0.8", "pairs.hard_negative_share=0.3"])


def test_negatives_respect_continuous_symmetry(composer):
    comp, obj = composer("pairs", "can")
    out = comp.pairs(np.random.default_rng(1), 100)
    rots, axes = symmetry_set(obj.symmetries_discrete, obj.symmetries_continuous)
    sym = np.degrees(
        symmetric_angle(
            out["obs_R_allo"].astype(float), out["cand_R_allo"].astype(float), rots, axes
        )
    )
    np.testing.assert_allclose(sym, out["angle_deg"], atol=1e-2)
    assert sym[out["aligned"] == 0].min() >= 20.0
    # a rotation about the can's axis is no error at all
    R = random_rotations(5, np.random.default_rng(2))
    Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.all(symmetric_angle(R, R @ Rz, rots, axes) < 1e-6)


def test_zero_perturbation_positive_lines_up(composer):
    comp, _ = composer(
        "pairs",
        "mug",
        "pairs.positive_share=1.0",
        "pairs.pos_rot_sigma_deg=0.0",
        "pairs.pos_rot_max_deg=0.0",
        "crop_jitter.xy_sigma=0.0",
        "crop_jitter.z_sigma=0.0",
        "occlusion.prob=0.0",
    )
    out = comp.pairs(np.random.default_rng(3), 30, debug=True)
    clean = np.asarray(comp.obs.clean_mask)[out["entry"]]
    iou_clean = np.array([_iou(a, b) for a, b in zip(out["obs_mask"], clean, strict=True)])
    iou_cand = np.array(
        [_iou(a, b) for a, b in zip(out["obs_mask"], out["cand_mask"], strict=True)]
    )
    # observed crop (cut from the off-centre window) vs the codebook render at the same
    # allocentric orientation: the same silhouette up to perspective / pixel rounding
    assert iou_clean.min() > 0.85 and np.median(iou_clean) > 0.92
    # vs the nearest entry of a coarse 200-entry grid: still mostly overlapping
    assert np.median(iou_cand) > 0.6
    assert np.all(out["visib_fract"] == 1.0)


def test_window_is_the_trackers_crop(composer):
    """Window geometry: a crop cut from the window through crop_to_window_affines equals the
    crop chpf.crops would cut from the full frame (here the full frame is rendered)."""
    from chpf.render import Renderer

    comp, obj = composer()
    e = 3
    K, t = np.asarray(comp.obs.K[e]), np.asarray(comp.obs.t[e])
    W, H = 640, 480
    full = Renderer(W, H).render([(obj, np.asarray(comp.obs.R_ego[e]), t)], K)
    t_est = t + np.array([0.004, -0.003, 0.02])
    A = crop_affines(t_est[None], K, comp.spec)
    from_full = extract_crops(full.masks[0], A, comp.S)[0]
    from data_gen.pool import crop_to_window_affines

    M = crop_to_window_affines(
        t_est[None], K[None], np.asarray(comp.obs.win_affine[e])[None], comp.spec
    )
    from_win = extract_crops(np.asarray(comp.obs.mask[e]), M, comp.S)[0]
    assert _iou(from_full, from_win) > 0.93
    # the window intrinsics place the projection of t at the window centre
    Kw = window_intrinsics(K, np.asarray(comp.obs.win_affine[e]))
    uv = Kw @ t / t[2]
    np.testing.assert_allclose(uv[:2], (comp.P - 1) / 2, atol=1e-6)


def test_occlusion_hides_the_configured_fraction(composer):
    comp, _ = composer(
        "ae",
        "mug",
        "occlusion.prob=1.0",
        "occlusion.fraction_range=[0.4, 0.4]",
        "empty_crops.ae_share=0.0",
    )
    rng = np.random.default_rng(4)
    vis = []
    for e in range(40):
        win, obj_mask, visible, v = comp.compose_window(e, rng)
        assert v == pytest.approx(visible.sum() / obj_mask.sum())
        assert not np.any(visible & ~obj_mask)
        vis.append(v)
        # the hidden object pixels really show something else
        hidden = obj_mask & ~visible
        changed = np.abs(win.astype(int) - np.asarray(comp.obs.rgb[e, 0], int)).sum(-1) > 0
        assert changed[hidden].mean() > 0.8
    vis = np.array(vis)
    assert np.median(np.abs(vis - 0.6)) < 0.05
    assert np.mean(np.abs(vis - 0.6) < 0.1) > 0.8
    # crop level: visib_fract agrees with the warped masks
    out = comp.ae(rng, 30, debug=True)
    crop_vis = out["input_visible_mask"].sum((1, 2)) / out["input_mask"].sum((1, 2))
    assert np.median(np.abs(crop_vis - out["visib_fract"])) < 0.05
    # heavy occlusion is still kept
    comp2, _ = composer(
        "pairs",
        "mug",
        "occlusion.prob=1.0",
        "occlusion.fraction_range=[0.7, 0.7]",
        "empty_crops.pairs_negative_share=0.0",
    )
    out2 = comp2.pairs(np.random.default_rng(5), 40)
    assert np.median(out2["visib_fract"]) < 0.4 and out2["aligned"].sum() == 20


def test_ae_targets(composer):
    comp, _ = composer("ae", "mug", "crop_jitter.ae_target=centred", "empty_crops.ae_share=0.0")
    out = comp.ae(np.random.default_rng(6), 20, debug=True)
    e = out["entry"]
    np.testing.assert_array_equal(out["target_rgb"], np.asarray(comp.obs.clean_rgb)[e])
    np.testing.assert_array_equal(out["target_mask"], np.asarray(comp.obs.clean_mask)[e])
    assert out["target_mask"].sum((1, 2)).min() > 50
    R = out["R_allo"].astype(float)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-5
    )
    # the input is the observed crop: background around the object, not black
    bg = ~out["target_mask"]
    assert out["input_rgb"][bg].mean() > 5


def test_followed_ae_targets_are_cut_like_the_jittered_input(composer):
    """ae_target=follow: the target shows the object where the jittered input crop has it."""
    jitter = (
        "crop_jitter.xy_sigma=0.15",
        "crop_jitter.z_sigma=0.15",
        "occlusion.prob=0.0",
        "empty_crops.ae_share=0.0",
    )
    ious = {}
    for mode in ("follow", "centred"):
        comp, _ = composer("ae", "mug", f"crop_jitter.ae_target={mode}", *jitter)
        out = comp.ae(np.random.default_rng(7), 30, debug=True)
        ious[mode] = np.array(
            [_iou(a, b) for a, b in zip(out["target_mask"], out["input_mask"], strict=True)]
        )
        shift = np.abs(out["t_est"] - np.asarray(comp.obs.t)[out["entry"]]).sum(1)
        assert shift.min() > 0  # every input really is jittered
    assert np.median(ious["follow"]) > 0.85
    assert np.median(ious["follow"]) > np.median(ious["centred"]) + 0.1


def test_empty_pair_negatives_hold_no_object(composer):
    """A share of the negatives shows background and clutter only (a particle far off)."""
    comp, _ = composer("pairs", "mug", "empty_crops.pairs_negative_share=0.5")
    out = comp.pairs(np.random.default_rng(8), 60, debug=True)
    empty = out["visib_fract"] == 0
    assert 5 <= empty.sum() <= 25
    assert np.all(out["aligned"][empty] == 0)
    assert not out["obs_mask"][empty].any() and out["obs_mask"][~empty].sum((1, 2)).min() > 0
    assert out["obs_rgb"][empty].std() > 5  # background, not a black crop


def test_scale_negatives_are_right_in_orientation_and_wrong_in_depth(composer):
    """A share of the negatives is drawn like a positive but cut at a depth off by a factor in
    the configured range (nearer and farther); every other crop stays within half its low end,
    and depth_ratio records z_crop / z for each pair."""
    comp, _ = composer("pairs", "mug", "pairs.scale_negative_share=0.5", "crop_jitter.z_sigma=0.2")
    out = comp.pairs(np.random.default_rng(3), 200, debug=True)
    true_z = np.asarray(comp.obs.t)[out["entry"], 2]
    np.testing.assert_allclose(out["depth_ratio"], out["t_est"][:, 2] / true_z, rtol=1e-6)
    log_r = np.log(out["depth_ratio"])
    scaled = np.abs(log_r) >= 0.12 - 1e-6
    assert 25 <= scaled.sum() <= 75
    assert np.all(out["aligned"][scaled] == 0)
    assert np.all(out["angle_deg"][scaled] <= 10.0 + grid_spacing_deg(comp.grid)["max"] + 1e-3)
    assert np.abs(log_r[scaled]).max() <= 0.4 + 1e-6
    assert (log_r[scaled] > 0).any() and (log_r[scaled] < 0).any()
    # z_sigma 0.2 would put many crops past 0.06: they are held within it
    assert np.abs(log_r[~scaled]).max() <= 0.06 + 1e-6 and np.ptp(log_r[~scaled]) > 0.1


def test_without_scale_negatives_the_depth_jitter_is_untouched(composer):
    comp, _ = composer("pairs", "mug", "crop_jitter.z_sigma=0.2")
    out = comp.pairs(np.random.default_rng(3), 100)
    assert np.abs(np.log(out["depth_ratio"])).max() > 0.12  # no clipping, no scale negatives
    assert not depth_off(out["depth_ratio"], {"scale_negative_share": 0.0}).any()


def test_depth_off_reads_the_datas_range():
    cfg = {"scale_negative_share": 0.3, "scale_negative_range": [0.12, 0.4]}
    ratio = np.exp([0.0, 0.059, -0.061, 0.2, -0.3])
    np.testing.assert_array_equal(depth_off(ratio, cfg), [False, False, True, True, True])
