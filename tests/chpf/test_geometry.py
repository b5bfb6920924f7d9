"""Tests of chpf.geometry: conversions, sampling, the SO(3) grid, averaging, camera geometry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from chpf import geometry as geo


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _assert_rotations(R: np.ndarray, atol: float = 1e-10) -> None:
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, eye, atol=atol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=atol)


def _special_rotations() -> np.ndarray:
    """Identity, half-turns (w = 0 quaternions) and other edge cases."""
    vecs = np.array(
        [
            [0.0, 0.0, 0.0],
            [np.pi, 0.0, 0.0],
            [0.0, np.pi, 0.0],
            [0.0, 0.0, np.pi],
            np.pi * np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0),
            np.pi * np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0),
            [1e-9, 0.0, 0.0],
            [0.0, 3.0, 0.0],
        ]
    )
    return Rotation.from_rotvec(vecs).as_matrix()


# --- conversions -------------------------------------------------------------------------------


def test_quat_to_matrix_matches_scipy_and_is_a_rotation():
    q = _rng().standard_normal((500, 4))
    R = geo.quat_to_matrix(q)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    np.testing.assert_allclose(R, ref, atol=1e-12)
    _assert_rotations(R)


def test_quat_matrix_round_trip_and_canonical_sign():
    q = _rng(1).standard_normal((1000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q_back = geo.matrix_to_quat(geo.quat_to_matrix(q))
    assert np.all(q_back[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q_back, axis=1), 1.0, atol=1e-12)
    q_canon = np.where(q[:, :1] < 0, -q, q)
    np.testing.assert_allclose(q_back, q_canon, atol=1e-12)


def test_matrix_quat_matrix_round_trip_including_half_turns():
    R = np.concatenate([_special_rotations(), geo.random_rotations(200, _rng(2))])
    q = geo.matrix_to_quat(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(geo.quat_to_matrix(q), R, atol=1e-12)


def test_conversions_keep_batch_shape():
    R = geo.random_rotations(6, _rng(3)).reshape(2, 3, 3, 3)
    assert geo.matrix_to_quat(R).shape == (2, 3, 4)
    assert geo.matrix_to_axis_angle(R).shape == (2, 3, 3)
    assert geo.quat_to_matrix(geo.matrix_to_quat(R)).shape == (2, 3, 3, 3)
    assert geo.axis_angle_to_matrix(np.zeros(3)).shape == (3, 3)


def test_axis_angle_matches_scipy_and_round_trips():
    rng = _rng(4)
    axes = rng.standard_normal((500, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0.0, np.pi - 1e-6, 495), [0.0, 1e-12, 1e-7, 1e-4, 2e-4]])
    v = axes * angles[:, None]
    R = geo.axis_angle_to_matrix(v)
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    _assert_rotations(R)
    np.testing.assert_allclose(geo.matrix_to_axis_angle(R), v, atol=1e-9)


def test_axis_angle_identity_and_half_turn_have_no_nan():
    assert np.all(geo.matrix_to_axis_angle(np.eye(3)) == 0.0)
    v = geo.matrix_to_axis_angle(_special_rotations())
    assert np.all(np.isfinite(v))
    np.testing.assert_allclose(np.linalg.norm(v[1:6], axis=1), np.pi, atol=1e-12)
    np.testing.assert_allclose(geo.axis_angle_to_matrix(v), _special_rotations(), atol=1e-12)


# --- random rotations and perturbations ---------------------------------------------------------


def _haar_angle_cdf(theta: np.ndarray) -> np.ndarray:
    """CDF of the rotation angle of a Haar-random rotation: (theta - sin theta) / pi."""
    return (theta - np.sin(theta)) / np.pi


def test_random_rotations_are_uniform():
    R = geo.random_rotations(20000, _rng(5))
    assert R.shape == (20000, 3, 3)
    _assert_rotations(R)
    q = geo.matrix_to_quat(R)
    # E[q q^T] = I / 4 for the Haar measure (q q^T does not depend on the sign of q).
    np.testing.assert_allclose(q.T @ q / len(q), np.eye(4) / 4, atol=0.01)
    angles = geo.geodesic_angle(np.eye(3), R)
    assert stats.kstest(angles, _haar_angle_cdf).pvalue > 1e-3


def test_angle_distribution_check_rejects_a_non_uniform_sampler():
    """Negative control: uniform axis + uniform angle is NOT Haar, and the KS check sees it."""
    rng = _rng(6)
    axes = rng.standard_normal((20000, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R = geo.axis_angle_to_matrix(axes * rng.uniform(0, np.pi, (20000, 1)))
    angles = geo.geodesic_angle(np.eye(3), R)
    assert stats.kstest(angles, _haar_angle_cdf).pvalue < 1e-6


def test_random_rotations_are_reproducible():
    np.testing.assert_array_equal(
        geo.random_rotations(5, _rng(7)), geo.random_rotations(5, _rng(7))
    )


def test_perturb_rotations_left_multiplies_gaussian_axis_angle():
    R = geo.random_rotations(1000, _rng(8))
    sigma = 0.05
    out = geo.perturb_rotations(R, sigma, _rng(9))
    w = _rng(9).standard_normal((1000, 3)) * sigma
    np.testing.assert_allclose(out, geo.axis_angle_to_matrix(w) @ R, atol=1e-12)
    _assert_rotations(out)
    np.testing.assert_allclose(geo.perturb_rotations(R, 0.0, _rng(0)), R, atol=1e-15)


def test_perturb_rotations_noise_statistics():
    n, sigma = 20000, 0.05
    R = np.broadcast_to(geo.random_rotations(1, _rng(10)), (n, 3, 3))
    out = geo.perturb_rotations(R, sigma, _rng(11))
    w = geo.matrix_to_axis_angle(out @ np.swapaxes(R, 1, 2))  # left noise: R' R^T = exp(w)
    np.testing.assert_allclose(w.mean(axis=0), 0.0, atol=0.003)
    np.testing.assert_allclose(np.cov(w.T), sigma**2 * np.eye(3), atol=0.1 * sigma**2)


# --- geodesic angle ------------------------------------------------------------------------------


def test_geodesic_angle_known_values_and_broadcasting():
    angles = np.array([0.0, 1e-8, 0.3, 2.0, np.pi - 1e-7, np.pi])
    axis = np.array([0.36, 0.48, 0.8])
    R = geo.axis_angle_to_matrix(axis * angles[:, None])
    R0 = geo.random_rotations(1, _rng(12))[0]
    # R0 R vs R0: the relative rotation is R.
    np.testing.assert_allclose(geo.geodesic_angle(R0, R0 @ R), angles, atol=1e-12)
    np.testing.assert_allclose(geo.geodesic_angle(R0 @ R, R0), angles, atol=1e-12)
    assert geo.geodesic_angle(R0, R0 @ R).shape == (6,)
    A = geo.random_rotations(8, _rng(13)).reshape(2, 4, 3, 3)
    B = geo.random_rotations(4, _rng(14))
    out = geo.geodesic_angle(A, B)
    assert out.shape == (2, 4)
    assert np.all((out >= 0) & (out <= np.pi))


# --- SO(3) grid ----------------------------------------------------------------------------------


def test_so3_grid_is_deterministic_and_valid():
    G = geo.so3_grid(1000)
    assert G.shape == (1000, 3, 3)
    _assert_rotations(G)
    np.testing.assert_array_equal(G, geo.so3_grid(1000))
    assert geo.so3_grid(1).shape == (1, 3, 3)
    with pytest.raises(ValueError):
        geo.so3_grid(0)
    # No two entries describe the same rotation.
    grid = geo.RotationGrid(G)
    q = grid.quats
    gram = np.abs(q @ q.T) - 2.0 * np.eye(len(q))
    assert gram.max() < np.cos(np.radians(1.0) / 2)


def _nearest_angles(grid: geo.RotationGrid, queries: np.ndarray) -> np.ndarray:
    return geo.geodesic_angle(grid.rotations[grid.nearest(queries)], queries)


def _spacing_radius(k: int) -> float:
    """Radius r0 of a geodesic ball holding 1/k of SO(3): (r - sin r)/pi = 1/k, r ~ (6 pi/k)^(1/3).

    A random query's distance to the nearest of k points has mean >= 0.75 r0 for ANY k-point
    set (equality for ball-shaped cells); for k uniformly random points it is ~0.89 r0.
    """
    return (6.0 * np.pi / k) ** (1.0 / 3.0)


def test_so3_grid_covers_better_than_random_points():
    k = 2000
    queries = geo.random_rotations(20000, _rng(15))
    grid = geo.RotationGrid.uniform(k)
    random_set = geo.RotationGrid(geo.random_rotations(k, _rng(16)))
    a_grid = _nearest_angles(grid, queries)
    a_rand = _nearest_angles(random_set, queries)
    r0 = _spacing_radius(k)
    assert 0.72 * r0 < a_grid.mean() < 0.85 * r0
    assert a_grid.mean() < 0.93 * a_rand.mean()
    assert np.median(a_grid) < np.median(a_rand)
    # Covering radius (max nearest angle): a grid has no large holes, a random set does.
    assert a_grid.max() < 1.6 * r0
    assert a_grid.max() < 0.8 * a_rand.max()


def test_so3_grid_spacing_scales_like_k_to_minus_one_third():
    queries = geo.random_rotations(20000, _rng(17))
    m1 = _nearest_angles(geo.RotationGrid.uniform(1000), queries).mean()
    m8 = _nearest_angles(geo.RotationGrid.uniform(8000), queries).mean()
    assert 1.8 < m1 / m8 < 2.2  # 8^(1/3) = 2


def test_rotation_grid_nearest_matches_brute_force(monkeypatch):
    grid = geo.RotationGrid.uniform(500)
    assert len(grid) == 500
    assert grid.quats.shape == (500, 4)
    assert np.all(grid.quats[:, 0] >= 0)
    # Random queries plus half-turns (w = 0: the sign of q is ambiguous there).
    R = np.concatenate([geo.random_rotations(300, _rng(18)), _special_rotations()])
    angles = geo.geodesic_angle(grid.rotations[None], R[:, None])  # (N, K)
    idx = grid.nearest(R)
    assert idx.dtype == np.int64 and idx.shape == (len(R),)
    np.testing.assert_allclose(angles[np.arange(len(R)), idx], angles.min(axis=1), atol=1e-12)
    scores = np.abs(geo.matrix_to_quat(R) @ grid.quats.T)
    np.testing.assert_array_equal(idx, np.argmax(scores, axis=1))
    # Small chunks give the same answer.
    monkeypatch.setattr(geo, "_NEAREST_CHUNK_ROWS", 7)
    np.testing.assert_array_equal(grid.nearest(R), idx)
    # Grid entries find themselves; leading shapes are kept.
    np.testing.assert_array_equal(grid.nearest(grid.rotations), np.arange(500))
    assert grid.nearest(R[:300].reshape(3, 100, 3, 3)).shape == (3, 100)
    assert geo.RotationGrid(np.eye(3)[None]).nearest(R).tolist() == [0] * len(R)


# --- averaging -----------------------------------------------------------------------------------


def test_average_of_symmetric_perturbations_is_the_centre():
    rng = _rng(19)
    R0 = geo.random_rotations(1, rng)[0]
    v = rng.standard_normal((20, 3)) * 0.3
    R = np.concatenate([R0 @ geo.axis_angle_to_matrix(v), R0 @ geo.axis_angle_to_matrix(-v)])
    q = geo.matrix_to_quat(R)
    q[::3] *= -1.0  # the sign of a quaternion must not matter
    mean = geo.average_quaternions(q)
    assert mean.shape == (4,) and mean[0] >= 0
    np.testing.assert_allclose(mean, geo.matrix_to_quat(R0), atol=1e-9)


def test_average_quaternions_honours_weights():
    axis = np.array([0.0, 0.6, 0.8])
    theta = np.radians(60.0)
    qa = geo.matrix_to_quat(np.eye(3))
    qb = geo.matrix_to_quat(geo.axis_angle_to_matrix(axis * theta))
    q = np.stack([qa, qb])
    # Both quaternions lie in a plane: the principal direction of 3 qa qa^T + qb qb^T has
    # angle psi with tan(2 psi) = sin(theta) / (3 + cos(theta)); the rotation angle is 2 psi.
    expected = np.arctan2(np.sin(theta), 3.0 + np.cos(theta))
    mean = geo.average_quaternions(q, np.array([3.0, 1.0]))
    R_expected = geo.axis_angle_to_matrix(axis * expected)
    np.testing.assert_allclose(geo.quat_to_matrix(mean), R_expected, atol=1e-12)
    # Weights are normalised; zero weight ignores an entry; None = equal weights.
    np.testing.assert_allclose(mean, geo.average_quaternions(q, np.array([0.75, 0.25])), atol=1e-12)
    np.testing.assert_allclose(geo.average_quaternions(q, np.array([0.0, 2.0])), qb, atol=1e-12)
    half = geo.quat_to_matrix(geo.average_quaternions(q))
    np.testing.assert_allclose(half, geo.axis_angle_to_matrix(axis * theta / 2), atol=1e-12)


def test_average_quaternions_rejects_bad_weights():
    q = geo.matrix_to_quat(geo.random_rotations(3, _rng(20)))
    for w in ([1.0, -1.0, 1.0], [0.0, 0.0, 0.0], [1.0, np.nan, 1.0], [1.0, 1.0]):
        with pytest.raises(ValueError):
            geo.average_quaternions(q, np.array(w))


# --- rays, allocentric frames, projection -------------------------------------------------------


def test_ray_rotation_maps_optical_axis_onto_the_ray():
    rng = _rng(21)
    t = rng.standard_normal((500, 3)) * [0.3, 0.3, 1.0] + np.array([0.0, 0.0, 1.0])
    R = geo.ray_rotation(t)
    assert R.shape == (500, 3, 3)
    _assert_rotations(R, atol=1e-12)
    d = t / np.linalg.norm(t, axis=1, keepdims=True)
    np.testing.assert_allclose(R[:, :, 2], d, atol=1e-12)
    # Minimal: the rotation angle equals the angle between z and the ray, about z x d.
    np.testing.assert_allclose(geo.geodesic_angle(np.eye(3), R), np.arccos(d[:, 2]), atol=1e-7)
    axis = np.cross([0.0, 0.0, 1.0], d)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, axis), axis, atol=1e-12)


def test_ray_rotation_edge_cases():
    eye = np.broadcast_to(np.eye(3), (3, 3, 3))
    on_axis = geo.ray_rotation(np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1e-9], [0.0, 0.0, 0.0]]))
    np.testing.assert_array_equal(on_axis, eye)
    back = geo.ray_rotation(np.array([[0.0, 0.0, -1.0], [1e-9, -2e-9, -1.0], [1e-3, 0.0, -1.0]]))
    assert np.all(np.isfinite(back))
    _assert_rotations(back, atol=1e-12)
    d = np.array([[0.0, 0.0, -1.0], [1e-9, -2e-9, -1.0], [1e-3, 0.0, -1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(back[:, :, 2], d, atol=1e-12)
    assert geo.ray_rotation(np.array([0.1, 0.2, 1.0])).shape == (3, 3)


def test_ray_rotation_forward_path_is_the_general_formula_bit_for_bit():
    """Rays with z >= 0 take a shorter path (``_forward_ray_rotation``); a batch holding one
    ray behind the camera takes the general one: the shared rows are the same bytes."""
    rng = _rng(24)
    t = rng.standard_normal((300, 3)) * 10.0 ** rng.uniform(-4, 2, (300, 1))
    t[:, 2] = np.abs(t[:, 2])
    t[0, 2] = 0.0  # in the image plane, still z >= 0
    t[1] = [0.0, 0.0, 3.0]
    forward = geo.ray_rotation(t)
    general = geo.ray_rotation(np.vstack([t, [[0.1, 0.0, -1.0]]]))[:-1]
    np.testing.assert_array_equal(forward, general)
    np.testing.assert_array_equal(
        forward, geo._forward_ray_rotation(t / np.linalg.norm(t, axis=1)[:, None])
    )
    _assert_rotations(forward, atol=1e-12)


def test_allocentric_egocentric_round_trip():
    rng = _rng(22)
    R = geo.random_rotations(100, rng)
    t = rng.uniform(-0.3, 0.3, (100, 3)) + np.array([0.0, 0.0, 1.0])
    R_allo = geo.egocentric_to_allocentric(R, t)
    _assert_rotations(R_allo)
    np.testing.assert_allclose(geo.allocentric_to_egocentric(R_allo, t), R, atol=1e-12)
    # On the optical axis both frames agree.
    t_axis = np.array([0.0, 0.0, 0.7])
    np.testing.assert_allclose(geo.egocentric_to_allocentric(R, t_axis), R, atol=1e-15)
    # An object turned to face the camera along its ray has the same allocentric rotation.
    R0 = geo.random_rotations(1, rng)[0]
    facing = geo.ray_rotation(t) @ R0
    np.testing.assert_allclose(
        geo.egocentric_to_allocentric(facing, t), np.broadcast_to(R0, (100, 3, 3)), atol=1e-12
    )


def test_project_points_matches_hand_values_and_opencv():
    K = np.array([[500.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    X = np.array([[0.0, 0.0, 1.0], [0.1, -0.2, 2.0]])
    expected = np.array([[320.0, 240.0], [320.0 + 500 * 0.05, 240.0 - 400 * 0.1]])
    np.testing.assert_allclose(geo.project_points(X, K), expected, atol=1e-12)
    pts = _rng(23).uniform(-0.5, 0.5, (2, 50, 3)) + np.array([0.0, 0.0, 2.0])
    uv = geo.project_points(pts, K)
    assert uv.shape == (2, 50, 2)
    ref, _ = cv2.projectPoints(pts.reshape(-1, 3), np.zeros(3), np.zeros(3), K, None)
    np.testing.assert_allclose(uv.reshape(-1, 2), ref.reshape(-1, 2), atol=1e-9)


def test_check_image_size_against_the_principal_point():
    K = np.array([[600.0, 0, 319.5], [0, 600, 239.5], [0, 0, 1]])
    geo.check_image_size(640, 480, K)
    geo.check_image_size(600, 500, K)  # within 20 %: an off-centre principal point is fine
    for w, h in ((320, 240), (640, 240), (1280, 480), (640, 370)):
        with pytest.raises(geo.ImageSizeError, match=f"image is {w}x{h} .* 640x480"):
            geo.check_image_size(w, h, K)
    geo.check_image_size(640, 370, K, tol=0.3)
