"""Tests of chpf.metrics: ADD, ADD-S (hand-computed cases, batch agreement) and the VOCap AUC."""

from __future__ import annotations

import numpy as np
import pytest

from chpf import geometry as geo
from chpf import metrics
from tests.helpers import vocap_reference

I3 = np.eye(3)
Z3 = np.zeros(3)


def _rot_z(angle: float) -> np.ndarray:
    return geo.axis_angle_to_matrix(np.array([0.0, 0.0, angle]))


# --- ADD / ADD-S ---------------------------------------------------------------------------------


def test_translated_model_far_apart_points():
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    t_gt = np.array([0.1, -0.2, 1.0])
    t_est = t_gt + np.array([0.003, 0.0, 0.004])  # |shift| = 5 mm
    assert metrics.add(pts, I3, t_est, I3, t_gt) == pytest.approx(0.005, abs=1e-15)
    assert metrics.adds(pts, I3, t_est, I3, t_gt) == pytest.approx(0.005, abs=1e-15)


def test_translated_line_model_adds_uses_nearest_points():
    # est points x = 0.1, 0.2, 0.3; gt points x = 0, 0.1, 0.2: nearest distances 0.1, 0, 0.
    pts = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    t_est = np.array([0.1, 0.0, 0.0])
    assert metrics.add(pts, I3, t_est, I3, Z3) == pytest.approx(0.1, abs=1e-15)
    assert metrics.adds(pts, I3, t_est, I3, Z3) == pytest.approx(0.1 / 3, abs=1e-15)


def test_rotated_single_point():
    pts = np.array([[0.1, 0.0, 0.0]])
    R = _rot_z(np.pi / 2)  # (0.1, 0, 0) -> (0, 0.1, 0)
    assert metrics.add(pts, R, Z3, I3, Z3) == pytest.approx(0.1 * np.sqrt(2), abs=1e-15)
    assert metrics.adds(pts, R, Z3, I3, Z3) == pytest.approx(0.1 * np.sqrt(2), abs=1e-15)


def test_symmetric_model_adds_zero_add_positive():
    n, r = 12, 0.05
    phi = 2 * np.pi * np.arange(n) / n
    pts = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)], axis=1)
    t = np.array([0.0, 0.0, 0.8])
    R_gt = geo.random_rotations(1, np.random.default_rng(0))[0]
    R_est = R_gt @ _rot_z(2 * np.pi / n)  # a symmetry of the 12-gon
    chord = 2 * r * np.sin(np.pi / n)
    assert metrics.add(pts, R_est, t, R_gt, t) == pytest.approx(chord, abs=1e-14)
    assert metrics.adds(pts, R_est, t, R_gt, t) == pytest.approx(0.0, abs=1e-12)


def _random_poses(p: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    R_gt = geo.random_rotations(p, rng)
    R_est = geo.perturb_rotations(R_gt, 0.3, rng)
    R_est[: p // 4] = geo.random_rotations(p // 4, rng)  # some far-off estimates
    t_gt = rng.uniform(-0.2, 0.2, (p, 3)) + np.array([0.0, 0.0, 1.0])
    t_est = t_gt + rng.normal(0.0, 0.02, (p, 3))
    return R_est, t_est, R_gt, t_gt


def _adds_brute(pts, R_est, t_est, R_gt, t_gt) -> float:
    """ADD-S by the definition: est-posed and gt-posed points, full distance matrix."""
    est = pts @ R_est.T + t_est
    gt = pts @ R_gt.T + t_gt
    dist = np.linalg.norm(gt[:, None, :] - est[None, :, :], axis=-1)
    return float(dist.min(axis=1).mean())


def test_batch_agrees_with_single_and_with_the_definition(monkeypatch):
    rng = np.random.default_rng(1)
    pts = rng.normal(0.0, 0.05, (150, 3)) * [1.0, 0.5, 2.0]
    R_est, t_est, R_gt, t_gt = _random_poses(40, rng)
    add_b = metrics.add_batch(pts, R_est, t_est, R_gt, t_gt)
    adds_b = metrics.adds_batch(pts, R_est, t_est, R_gt, t_gt)
    assert add_b.shape == (40,) and adds_b.shape == (40,)
    for i in range(40):
        poses = (R_est[i], t_est[i], R_gt[i], t_gt[i])
        assert add_b[i] == pytest.approx(metrics.add(pts, *poses), abs=1e-14)
        assert adds_b[i] == pytest.approx(metrics.adds(pts, *poses), abs=1e-14)
        assert adds_b[i] == pytest.approx(_adds_brute(pts, *poses), abs=1e-12)
        moved = pts @ R_est[i].T + t_est[i] - (pts @ R_gt[i].T + t_gt[i])
        assert add_b[i] == pytest.approx(np.linalg.norm(moved, axis=1).mean(), abs=1e-14)
    assert np.all(adds_b <= add_b + 1e-15)
    assert np.all(adds_b > 0)
    # Chunking (several poses per chunk, and a chunk smaller than one pose) changes nothing.
    for pairs in (7 * 150, 1):
        monkeypatch.setattr(metrics, "_CHUNK_PAIRS", pairs)
        np.testing.assert_allclose(metrics.add_batch(pts, R_est, t_est, R_gt, t_gt), add_b)
        np.testing.assert_allclose(metrics.adds_batch(pts, R_est, t_est, R_gt, t_gt), adds_b)
    np.testing.assert_allclose(
        metrics.adds_batch(pts, R_est, t_est, R_gt, t_gt, workers=2), adds_b, atol=0
    )


def test_identical_poses_give_zero():
    rng = np.random.default_rng(2)
    pts = rng.normal(0.0, 0.05, (100, 3))
    R = geo.random_rotations(5, rng)
    t = rng.normal(0.0, 0.1, (5, 3))
    np.testing.assert_allclose(metrics.add_batch(pts, R, t, R, t), 0.0, atol=1e-15)
    np.testing.assert_allclose(metrics.adds_batch(pts, R, t, R, t), 0.0, atol=1e-15)


def test_empty_batch_and_bad_shapes():
    pts = np.zeros((4, 3))
    empty_R, empty_t = np.zeros((0, 3, 3)), np.zeros((0, 3))
    assert metrics.add_batch(pts, empty_R, empty_t, empty_R, empty_t).shape == (0,)
    assert metrics.adds_batch(pts, empty_R, empty_t, empty_R, empty_t).shape == (0,)
    with pytest.raises(ValueError):
        metrics.add(np.zeros((4, 2)), I3, Z3, I3, Z3)
    with pytest.raises(ValueError):
        metrics.adds(np.zeros((0, 3)), I3, Z3, I3, Z3)
    with pytest.raises(ValueError):
        metrics.add_batch(pts, np.stack([I3, I3]), np.zeros((3, 3)), np.stack([I3, I3]), Z3[None])


# --- VOCap AUC -----------------------------------------------------------------------------------


def test_auc_hand_computed_values():
    # mrec = [0, 0.02, 0.06, 0.1], mpre = [0, 1/2, 1, 1]: 0.02/2 + 0.04 + 0.04 = 0.09 -> 90.
    assert metrics.auc(np.array([0.06, 0.02])) == pytest.approx(90.0, abs=1e-12)
    # mrec = [0, 0, 0.05, 0.1]: the zero-width step is skipped; 0.05 + 0.05 -> 100.
    assert metrics.auc([0.0, 0.05]) == pytest.approx(100.0, abs=1e-12)
    # One success anywhere below the threshold fills the whole area (the toolbox's rule).
    assert metrics.auc([0.09]) == pytest.approx(100.0, abs=1e-12)
    # Exactly at the threshold still counts; just above does not.
    assert metrics.auc([0.1]) == pytest.approx(100.0, abs=1e-12)
    assert metrics.auc([0.1 + 1e-9]) == 0.0
    # Another threshold: [0.02, 0.04] with 0.05: (0.02/2 + 0.02 + 0.01) / 0.05 -> 80.
    assert metrics.auc([0.02, 0.04], max_threshold=0.05) == pytest.approx(80.0, abs=1e-12)


def test_auc_missing_and_failed_estimates_lower_the_score():
    # n = 4, successes 0.02 and 0.06: 0.02/4 + 0.04/2 + 0.04/2 = 0.045 -> 45.
    assert metrics.auc([0.02, np.nan, 0.06, np.inf]) == pytest.approx(45.0, abs=1e-12)
    assert metrics.auc([0.5, 0.02, 0.06, 0.2]) == pytest.approx(45.0, abs=1e-12)
    assert metrics.auc(np.array([[0.02, np.nan], [0.06, 0.3]])) == pytest.approx(45.0, abs=1e-12)


def test_auc_ties():
    # mrec = [0, .03, .03, .08, .1], mpre = [0, 1/3, 2/3, 1, 1]: .03/3 + .05 + .02 = .08 -> 80.
    assert metrics.auc([0.03, 0.08, 0.03]) == pytest.approx(80.0, abs=1e-12)
    assert metrics.auc([0.0, 0.0, 0.0]) == pytest.approx(100.0, abs=1e-12)


def test_auc_edge_cases():
    assert metrics.auc([]) == 0.0
    assert metrics.auc(np.array([0.11, 0.5, 3.0])) == 0.0
    assert metrics.auc([np.nan, np.inf]) == 0.0
    with pytest.raises(ValueError):
        metrics.auc([-0.01, 0.02])
    with pytest.raises(ValueError):
        metrics.auc([0.01], max_threshold=0.0)


def test_auc_matches_toolbox_transcription_on_random_inputs():
    rng = np.random.default_rng(3)
    for trial in range(30):
        n = int(rng.integers(1, 60))
        e = np.round(rng.uniform(0.0, 0.15, n), 3 if trial % 2 else 9)  # rounding makes ties
        e[rng.random(n) < 0.1] = np.nan
        e[rng.random(n) < 0.05] = np.inf
        assert metrics.auc(e) == pytest.approx(vocap_reference(e), abs=1e-9)
        assert metrics.auc(e, 0.05) == pytest.approx(vocap_reference(e, 0.05), abs=1e-9)


def test_auc_large_sample_is_close_to_the_curve_area():
    # Errors uniform on [0, 0.2]: half succeed, accuracy(th) = th / 0.2 on [0, 0.1]: area 0.025
    # of 0.1 -> 25; the right-endpoint rule adds at most 100 / n.
    e = np.random.default_rng(4).uniform(0.0, 0.2, 20000)
    value = metrics.auc(e)
    exact = np.mean(np.clip(0.1 - e, 0.0, None)) / 0.1 * 100.0  # integral of accuracy(th)
    assert exact <= value <= exact + 100.0 / len(e) + 1e-9
    assert value == pytest.approx(25.0, abs=0.5)


def test_accuracy_counts_errors_below_their_threshold():
    # 0.01 < 0.05 yes; nan (missing) no; 0.2 < 0.5 yes; 0.05 < 0.05 no (strict, as BOP)
    e = [0.01, np.nan, 0.2, 0.05]
    assert metrics.accuracy(e, [0.05, 0.05, 0.5, 0.05]) == pytest.approx(50.0)
    assert metrics.accuracy(e, 0.04) == pytest.approx(25.0)  # only 0.01
    assert metrics.accuracy([], 0.1) == 0.0
