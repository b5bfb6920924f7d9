"""Tests of chpf.crops: CropSpec, affines, extraction, codebook renders, allocentric contract."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from chpf.crops import (
    CropBatch,
    CropSpec,
    _via_rgba,
    crop_affines,
    extract_crops,
    render_crops,
)
from chpf.errors import ConfigError
from chpf.objects import builtin_object
from chpf.render import Renderer

K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])


def ray_rotation(t: np.ndarray) -> np.ndarray:
    """Minimal rotation taking (0, 0, 1) onto t / |t| (independent of chpf.geometry)."""
    d = t / np.linalg.norm(t)
    axis = np.cross([0.0, 0.0, 1.0], d)
    angle = np.arctan2(np.linalg.norm(axis), d[2])
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def frame_renderer():
    r = Renderer(640, 480)
    yield r
    r.close()


@pytest.fixture(scope="module")
def drill():
    return builtin_object("drill")


def test_cropspec_rule_and_dict_roundtrip():
    spec = CropSpec.for_object(0.25, size=64)
    assert spec.size == 64
    assert spec.render_distance == pytest.approx(1.0)
    assert spec.focal == pytest.approx(3.6 * 64)
    np.testing.assert_allclose(spec.K, [[230.4, 0, 31.5], [0, 230.4, 31.5], [0, 0, 1]])
    # the diameter spans 90% of the crop at D_r
    assert spec.focal * 0.25 / spec.render_distance == pytest.approx(0.9 * 64)
    assert CropSpec.from_dict(spec.to_dict()) == spec
    assert CropSpec(64, 1.0, 230.4) == spec
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.size = 128  # type: ignore[misc]
    with pytest.raises(ConfigError):
        CropSpec.from_dict({"size": 64, "render_distance": 1.0})
    with pytest.raises(ConfigError):
        CropSpec.from_dict({**spec.to_dict(), "extra": 1})
    with pytest.raises(ConfigError):
        CropSpec(size=64, render_distance=-1.0, focal=100.0)


def test_crop_affines_centre_and_scale():
    spec = CropSpec.for_object(0.2, size=32)
    K2 = np.array([[500.0, 0.0, 300.0], [0.0, 550.0, 200.0], [0.0, 0.0, 1.0]])
    t = np.array([[0.1, -0.05, 0.8], [0.0, 0.0, 1.6]])
    A = crop_affines(t, K2, spec)
    assert A.shape == (2, 2, 3)
    c = (spec.size - 1) / 2
    centre = A[:, :, :2] @ np.array([c, c]) + A[:, :, 2]
    uv = (t @ K2.T)[:, :2] / t[:, 2:]
    np.testing.assert_allclose(centre, uv, atol=1e-9)
    s = spec.render_distance / t[:, 2]
    np.testing.assert_allclose(A[:, 0, 0], s * 500.0 / spec.focal)
    np.testing.assert_allclose(A[:, 1, 1], s * 550.0 / spec.focal)
    # side of the crop in image pixels
    np.testing.assert_allclose(A[:, 0, 0] * spec.size, spec.size * s * 500.0 / spec.focal)


def test_extract_crops_samples_the_mapped_pixels():
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    image = np.stack([xx, yy, xx + yy], axis=2)  # linear ramps: bilinear sampling is exact
    A = np.array([[[0.5, 0.0, 20.25], [0.0, 0.75, 30.5]], [[2.0, 0.0, 10.0], [0.0, 2.0, 5.0]]])
    crops = extract_crops(image, A, 16)
    assert crops.shape == (2, 16, 16, 3) and crops.dtype == np.float32
    jj, ii = np.mgrid[0:16, 0:16]
    for k in range(2):
        x = A[k, 0, 0] * ii + A[k, 0, 2]
        y = A[k, 1, 1] * jj + A[k, 1, 2]
        np.testing.assert_allclose(crops[k, :, :, 0], x, atol=0.05)
        np.testing.assert_allclose(crops[k, :, :, 1], y, atol=0.05)
    # grey image, outside -> border value; bool masks stay bool
    grey = extract_crops(xx, np.array([[[1.0, 0.0, -100.0], [0.0, 1.0, -100.0]]]), 8, border=7)
    assert grey.shape == (1, 8, 8) and (grey == 7).all()
    mask = np.zeros((h, w), bool)
    mask[40:80, 60:100] = True
    m = extract_crops(mask, np.array([[[1.0, 0.0, 50.0], [0.0, 1.0, 30.0]]]), 64)
    assert m.dtype == bool and m.sum() == 40 * 40
    # uint8 RGB, non-finite affine -> border
    rgb = np.full((h, w, 3), 9, np.uint8)
    out = extract_crops(rgb, np.array([[[np.inf, 0, 0], [0, 1, 0]], [[1, 0, 0], [0, 1, 0]]]), 4)
    assert out.dtype == np.uint8 and not out[0].any() and (out[1] == 9).all()


def test_render_crops_batch_and_renderer_reuse(drill):
    spec = CropSpec.for_object(drill.diameter, size=32)
    Rs = Rotation.random(3, random_state=0).as_matrix()
    batch = render_crops(None, drill, Rs, spec)
    assert isinstance(batch, CropBatch) and len(batch) == 3
    assert batch.rgb.shape == (3, 32, 32, 3) and batch.rgb.dtype == np.uint8
    assert batch.depth.shape == (3, 32, 32) and batch.depth.dtype == np.float32
    assert batch.mask.shape == (3, 32, 32) and batch.mask.dtype == bool
    np.testing.assert_array_equal(batch.mask, batch.depth > 0)
    d = batch.depth[batch.mask]
    r = drill.diameter / 2
    assert d.min() > spec.render_distance - r and d.max() < spec.render_distance + r
    # the object fits in the crop (its diameter spans 90% of it): the border stays empty
    assert not batch.mask[:, 0].any() and not batch.mask[:, -1].any()
    with Renderer(50, 40) as other:  # any renderer size works
        again = render_crops(other, drill, Rs, spec)
    np.testing.assert_array_equal(again.mask, batch.mask)
    np.testing.assert_allclose(again.rgb, batch.rgb, atol=2)
    fast = render_crops(None, drill, Rs, spec, antialias=False)
    np.testing.assert_array_equal(fast.mask, batch.mask)
    np.testing.assert_allclose(fast.depth, batch.depth, atol=1e-5)


def test_crops_are_scale_normalised(frame_renderer):
    can = builtin_object("can")
    spec = CropSpec.for_object(can.diameter, size=48)
    R = Rotation.from_euler("xyz", [70, 10, 30], degrees=True).as_matrix()
    masks, rgbs = [], []
    for z in (0.35, 0.7):
        t = np.array([0.0, 0.0, z])
        out = frame_renderer.render([(can, R, t)], K)
        A = crop_affines(t, K, spec)
        masks.append(extract_crops(out.masks[0].astype(np.float32), A, spec.size)[0] > 0.5)
        rgbs.append(extract_crops(out.rgb, A, spec.size)[0].astype(int))
    assert iou(masks[0], masks[1]) > 0.9
    # and both match the codebook render of the same (here also allocentric) rotation
    cb = render_crops(None, can, R[None], spec)
    assert iou(masks[0], cb.mask[0]) > 0.9 and iou(masks[1], cb.mask[0]) > 0.9
    both = masks[0] & cb.mask[0]
    assert np.abs(rgbs[0][both] - cb.rgb[0][both]).mean() < 20


def test_allocentric_contract(frame_renderer, drill):
    """An off-centre view cropped around t matches the codebook at R_ray(t)^T R, not at R.

    15 degrees off-axis the affine crop is still an approximation (the view is stretched by
    1/cos(15 deg) along the radial direction, plus perspective), hence IoU ~0.92, not ~0.98
    as on the axis.
    """
    spec = CropSpec.for_object(drill.diameter, size=64)
    rng = np.random.default_rng(0)
    ious_allo, ious_ego = [], []
    for seed in range(6):
        z = spec.render_distance
        phi = rng.uniform(0, 2 * np.pi)
        off = np.tan(np.deg2rad(15.0)) * z
        t = np.array([off * np.cos(phi), off * np.sin(phi), z])
        R = Rotation.random(random_state=seed).as_matrix()
        out = frame_renderer.render([(drill, R, t)], K)
        obs = extract_crops(out.masks[0].astype(np.float32), crop_affines(t, K, spec), 64)[0] > 0.5
        R_allo = ray_rotation(t).T @ R
        cb = render_crops(None, drill, np.stack([R_allo, R]), spec)
        ious_allo.append(iou(obs, cb.mask[0]))
        ious_ego.append(iou(obs, cb.mask[1]))
    assert min(ious_allo) > 0.85 and np.mean(ious_allo) > 0.9
    assert np.mean(ious_ego) < np.mean(ious_allo) - 0.1


def test_on_axis_crop_matches_codebook_closely(frame_renderer, drill):
    spec = CropSpec.for_object(drill.diameter, size=64)
    t = np.array([0.0, 0.0, spec.render_distance])
    for seed in range(2):
        R = Rotation.random(random_state=10 + seed).as_matrix()
        out = frame_renderer.render([(drill, R, t)], K)
        obs = extract_crops(out.masks[0].astype(np.float32), crop_affines(t, K, spec), 64)[0] > 0.5
        cb = render_crops(None, drill, R[None], spec)
        assert iou(obs, cb.mask[0]) > 0.96


def test_ray_rotation_agrees_with_geometry_if_present():
    geometry = pytest.importorskip("chpf.geometry")
    t = np.array([0.2, -0.1, 0.7])
    np.testing.assert_allclose(geometry.ray_rotation(t), ray_rotation(t), atol=1e-9)


def test_extract_crops_uses_inverse_map_convention():
    # crop pixel (i, j) = image pixel (i + 5, j + 3) for a unit-scale affine
    image = (np.arange(40 * 50) % 251).astype(np.uint8).reshape(40, 50)
    A = np.array([[[1.0, 0.0, 5.0], [0.0, 1.0, 3.0]]])
    crop = extract_crops(image, A, 10, interpolation=cv2.INTER_NEAREST)[0]
    np.testing.assert_array_equal(crop, image[3:13, 5:15])


def test_many_rgb_crops_are_the_bytes_of_one_rgb_warp_per_crop():
    """Many crops of a uint8 RGB image are warped as RGBA (``_via_rgba``): the same bytes as
    one three-channel warpAffine per crop, bilinear or nearest, inside, across and outside the
    image (border value), sheared, or with a non-finite affine (all border)."""
    rng = np.random.default_rng(3)
    h, w, n, s = 120, 160, 40, 32
    image = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    A = np.zeros((n, 2, 3))
    A[:, 0, 0] = rng.uniform(0.2, 6.0, n)
    A[:, 1, 1] = A[:, 0, 0] * rng.uniform(0.8, 1.2, n)
    A[:, 0, 2] = rng.uniform(-w, 2 * w, n)
    A[:, 1, 2] = rng.uniform(-h, 2 * h, n)
    A[::5, 0, 1], A[::5, 1, 0] = 0.3, -0.2
    A[7, 0, 2] = np.nan
    assert _via_rgba(image, n, s) and not _via_rgba(image, 1, 8)
    assert not _via_rgba(image[..., 0], n, s) and not _via_rgba(image.astype(np.float32), n, s)
    for interpolation in (cv2.INTER_LINEAR, cv2.INTER_NEAREST):
        for border in (0, 7):
            crops = extract_crops(image, A, s, interpolation, border)
            want = np.full((n, s, s, 3), border, np.uint8)
            for k in range(n):
                if k != 7:
                    want[k] = cv2.warpAffine(
                        image,
                        A[k],
                        (s, s),
                        flags=interpolation | cv2.WARP_INVERSE_MAP,
                        borderMode=cv2.BORDER_CONSTANT,
                        borderValue=(border,) * 3,
                    )
            assert crops.shape == want.shape and crops.dtype == np.uint8
            np.testing.assert_array_equal(crops, want)
