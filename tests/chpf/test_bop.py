"""Tests of chpf.bop: BOP layout round trip, a hand-written ycbv-style fixture, and bad input."""

# ruff: noqa: E501  (the ycbv fixture reproduces BOP toolkit JSON lines verbatim)

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from chpf import bop
from chpf.bop import (
    BopDataset,
    BopScene,
    CameraInfo,
    GtPose,
    ModelInfo,
    gt_info_from_masks,
)
from chpf.errors import BopFormatError, DatasetError, ImageSizeError

H, W = 48, 64
K = np.array([[80.0, 0.0, 31.5], [0.0, 81.0, 23.5], [0.0, 0.0, 1.0]])


def _rot(angle: float, axis: int) -> np.ndarray:
    v = np.zeros(3)
    v[axis] = angle
    R, _ = cv2.Rodrigues(v)
    return R


def _make_dataset(root: Path) -> dict:
    """Write a tiny dataset with every writer; return what was written (metres)."""
    rng = np.random.default_rng(0)
    sym_d = np.eye(4)
    sym_d[:3, :3] = _rot(np.pi, 2)
    sym_d[:3, 3] = [0.0, 0.0, 0.012]
    infos = {
        1: ModelInfo(
            1,
            0.172063,
            symmetries_discrete=[sym_d],
            min_xyz=np.array([-0.05, -0.06, -0.07]),
            size_xyz=np.array([0.1, 0.12, 0.14]),
        ),
        5: ModelInfo(
            5,
            0.05,
            symmetries_continuous=[
                {"axis": np.array([0.0, 0.0, 1.0]), "offset": np.array([0, 0, 0.003])}
            ],
        ),
    }
    bop.write_models_info(root / "models" / "models_info.json", infos)
    sdir = bop.scene_dir(root, "test", 3)
    cams = {
        0: CameraInfo(K.copy(), 0.1),
        1: CameraInfo(K.copy(), 1.0, R_w2c=_rot(0.3, 0), t_w2c=np.array([0.1, -0.2, 0.3])),
    }
    gt = {
        0: [
            GtPose(1, _rot(0.5, 1), np.array([0.01, -0.02, 0.7])),
            GtPose(5, np.eye(3), np.array([0, 0, 1.0])),
        ],
        1: [GtPose(5, _rot(-1.0, 2), np.array([-0.1, 0.05, 0.9]))],
    }
    bop.write_scene_camera(sdir / "scene_camera.json", cams)
    bop.write_scene_gt(sdir / "scene_gt.json", gt)
    images, depths, masks, ginfo = {}, {}, {}, {}
    for im_id in cams:
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        rgb[..., 0] = 250  # strong red: catches a BGR/RGB swap
        rgb[..., 2] = 5
        depth = rng.uniform(0.3, 2.0, (H, W)).astype(np.float32)
        depth[:5, :5] = 0.0
        ext = ".png" if im_id == 0 else ".jpg"
        bop.write_rgb(bop.rgb_path(sdir, im_id, ext), rgb)
        bop.write_depth(bop.depth_path(sdir, im_id), depth, depth_scale=cams[im_id].depth_scale)
        images[im_id], depths[im_id] = rgb, depth
        ginfo[im_id] = []
        for k in range(len(gt[im_id])):
            full = np.zeros((H, W), bool)
            full[10 + k : 30, 5 : 40 + k] = True
            vis = full.copy()
            vis[10:15] = False
            bop.write_mask(bop.mask_visib_path(sdir, im_id, k), vis)
            masks[(im_id, k)] = vis
            ginfo[im_id].append(gt_info_from_masks(full, vis, depth))
    bop.write_scene_gt_info(sdir / "scene_gt_info.json", ginfo)
    return {
        "infos": infos,
        "cams": cams,
        "gt": gt,
        "rgb": images,
        "depth": depths,
        "masks": masks,
        "ginfo": ginfo,
    }


def test_round_trip_whole_dataset(tmp_path: Path) -> None:
    w = _make_dataset(tmp_path)
    ds = BopDataset(tmp_path)
    assert ds.scene_ids("test") == [3]

    infos = ds.models_info()
    assert sorted(infos) == [1, 5]
    assert infos[1].diameter == pytest.approx(0.172063)
    np.testing.assert_allclose(
        infos[1].symmetries_discrete[0], w["infos"][1].symmetries_discrete[0]
    )
    np.testing.assert_allclose(infos[1].min_xyz, [-0.05, -0.06, -0.07])
    np.testing.assert_allclose(infos[1].size_xyz, [0.1, 0.12, 0.14])
    assert infos[1].symmetries_continuous == []
    np.testing.assert_allclose(infos[5].symmetries_continuous[0]["axis"], [0, 0, 1])
    np.testing.assert_allclose(infos[5].symmetries_continuous[0]["offset"], [0, 0, 0.003])
    assert infos[5].min_xyz is None

    sc = ds.scene("test", 3)
    assert sc.scene_id == 3 and sc.image_ids() == [0, 1]
    np.testing.assert_allclose(sc.cameras[0].K, K)
    assert sc.cameras[0].R_w2c is None and sc.cameras[0].depth_scale == 0.1
    np.testing.assert_allclose(sc.cameras[1].R_w2c, w["cams"][1].R_w2c)
    np.testing.assert_allclose(sc.cameras[1].t_w2c, [0.1, -0.2, 0.3])
    for im_id, poses in w["gt"].items():
        assert [p.obj_id for p in sc.gt[im_id]] == [p.obj_id for p in poses]
        for a, b in zip(sc.gt[im_id], poses, strict=True):
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)
            np.testing.assert_allclose(a.t, b.t, atol=1e-12)
        for a, b in zip(sc.gt_info[im_id], w["ginfo"][im_id], strict=True):
            assert a == b

    np.testing.assert_array_equal(sc.rgb(0), w["rgb"][0])
    jpg = sc.rgb(1).astype(int)  # lossy, but the colour order must survive
    assert jpg[..., 0].mean() > 200 and jpg[..., 2].mean() < 60
    for im_id, cam in w["cams"].items():
        d = sc.depth(im_id)
        assert d.dtype == np.float32 and d.shape == (H, W)
        assert np.abs(d - w["depth"][im_id]).max() <= cam.depth_scale / 1000 / 2 + 1e-6
        assert np.all(d[:5, :5] == 0)
    for (im_id, k), m in w["masks"].items():
        np.testing.assert_array_equal(sc.mask_visib(im_id, k), m)


def test_files_are_in_millimetres(tmp_path: Path) -> None:
    _make_dataset(tmp_path)
    sdir = tmp_path / "test" / "000003"
    gt = json.loads((sdir / "scene_gt.json").read_text())
    assert list(gt) == ["0", "1"]
    assert gt["0"][0]["obj_id"] == 1
    np.testing.assert_allclose(gt["0"][0]["cam_t_m2c"], [10.0, -20.0, 700.0])
    cam = json.loads((sdir / "scene_camera.json").read_text())
    np.testing.assert_allclose(cam["1"]["cam_t_w2c"], [100.0, -200.0, 300.0])
    assert len(cam["0"]["cam_K"]) == 9 and cam["0"]["depth_scale"] == 0.1
    info = json.loads((tmp_path / "models" / "models_info.json").read_text())
    assert info["1"]["diameter"] == pytest.approx(172.063)
    assert info["1"]["size_z"] == pytest.approx(140.0)
    assert info["1"]["symmetries_discrete"][0][11] == pytest.approx(12.0)
    assert info["5"]["symmetries_continuous"][0]["offset"] == pytest.approx([0, 0, 3.0])
    raw = cv2.imread(str(sdir / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    assert set(np.unique(cv2.imread(str(sdir / "mask_visib" / "000000_000001.png"), 0))) == {0, 255}
    gi = json.loads((sdir / "scene_gt_info.json").read_text())
    assert set(gi["0"][0]) == {
        "bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib", "visib_fract"
    }  # fmt: skip


def test_gt_info_from_masks() -> None:
    full = np.zeros((10, 12), bool)
    full[2:6, 3:9] = True
    vis = full.copy()
    vis[2:4] = False
    depth = np.ones((10, 12))
    depth[2, 3] = 0
    g = gt_info_from_masks(full, vis, depth)
    assert g.bbox_obj == (3, 2, 5, 3) and g.bbox_visib == (3, 4, 5, 1)
    assert (g.px_count_all, g.px_count_visib, g.px_count_valid) == (24, 12, 23)
    assert g.visib_fract == pytest.approx(0.5)
    empty = gt_info_from_masks(full, np.zeros_like(full))
    assert empty.bbox_visib == (-1, -1, -1, -1) and empty.visib_fract == 0


# --- a fixture laid out exactly as the BOP toolkit writes ycbv (test split, png images) -------

YCBV_MODELS_INFO = """{
  "1": {"diameter": 172.063, "min_x": -51.1445, "min_y": -51.1445, "min_z": -70.1879, "size_x": 102.289, "size_y": 102.289, "size_z": 140.376, "symmetries_discrete": [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]},
  "13": {"diameter": 169.511, "min_x": -80.5, "min_y": -80.5, "min_z": -27.5, "size_x": 161.0, "size_y": 161.0, "size_z": 55.0, "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]},
  "16": {"diameter": 201.549, "min_x": -60.0, "min_y": -92.0, "min_z": -28.0, "size_x": 120.0, "size_y": 184.0, "size_z": 56.0, "symmetries_discrete": [[-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 10.5, 0, 0, 0, 1], [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]]}
}"""

YCBV_SCENE_CAMERA = """{
  "1": {"cam_K": [1066.778, 0.0, 312.9869, 0.0, 1067.487, 241.3109, 0.0, 0.0, 1.0], "depth_scale": 0.1},
  "2": {"cam_K": [1066.778, 0.0, 312.9869, 0.0, 1067.487, 241.3109, 0.0, 0.0, 1.0], "depth_scale": 0.1}
}"""

YCBV_SCENE_GT = """{
  "1": [{"cam_R_m2c": [0.0, 1.0, 0.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0], "cam_t_m2c": [-68.3, 94.4, 866.9], "obj_id": 1}, {"cam_R_m2c": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "cam_t_m2c": [120.5, -10.25, 1003.0], "obj_id": 13}],
  "2": [{"cam_R_m2c": [0.0, 1.0, 0.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0], "cam_t_m2c": [-68.0, 94.0, 866.0], "obj_id": 1}]
}"""

YCBV_SCENE_GT_INFO = """{
  "1": [{"bbox_obj": [199, 263, 131, 176], "bbox_visib": [199, 263, 131, 176], "px_count_all": 16802, "px_count_valid": 16802, "px_count_visib": 16802, "visib_fract": 1.0}, {"bbox_obj": [380, 180, 200, 90], "bbox_visib": [380, 200, 150, 70], "px_count_all": 12000, "px_count_valid": 11900, "px_count_visib": 7400, "visib_fract": 0.6166666666666667}],
  "2": [{"bbox_obj": [198, 262, 131, 176], "bbox_visib": [198, 262, 131, 176], "px_count_all": 16790, "px_count_valid": 16790, "px_count_visib": 16790, "visib_fract": 1.0}]
}"""


def _write_ycbv(root: Path) -> Path:
    (root / "models").mkdir(parents=True)
    (root / "models" / "models_info.json").write_text(YCBV_MODELS_INFO)
    sdir = root / "test" / "000048"
    for sub in ("rgb", "depth", "mask_visib"):
        (sdir / sub).mkdir(parents=True)
    (sdir / "scene_camera.json").write_text(YCBV_SCENE_CAMERA)
    (sdir / "scene_gt.json").write_text(YCBV_SCENE_GT)
    (sdir / "scene_gt_info.json").write_text(YCBV_SCENE_GT_INFO)
    for im_id, n_inst in ((1, 2), (2, 1)):
        bgr = np.zeros((480, 640, 3), np.uint8)
        bgr[..., 0] = 255  # blue in OpenCV's BGR order
        cv2.imwrite(str(sdir / "rgb" / f"{im_id:06d}.png"), bgr)
        raw = np.full((480, 640), 8669, np.uint16)
        raw[0, 0] = 0
        cv2.imwrite(str(sdir / "depth" / f"{im_id:06d}.png"), raw)
        for k in range(n_inst):
            m = np.zeros((480, 640), np.uint8)
            m[263:439, 199:330] = 255
            cv2.imwrite(str(sdir / "mask_visib" / f"{im_id:06d}_{k:06d}.png"), m)
    return sdir


def test_reads_ycbv_layout(tmp_path: Path) -> None:
    _write_ycbv(tmp_path)
    ds = BopDataset(tmp_path)
    assert ds.scene_ids() == [48]
    info = ds.models_info()
    assert info[1].diameter == pytest.approx(0.172063)
    np.testing.assert_allclose(info[1].symmetries_discrete[0], np.diag([-1.0, -1, 1, 1]))
    np.testing.assert_allclose(info[16].symmetries_discrete[0][:3, 3], [0, 0, 0.0105])
    np.testing.assert_allclose(info[13].symmetries_continuous[0]["axis"], [0, 0, 1])
    np.testing.assert_allclose(info[13].min_xyz, [-0.0805, -0.0805, -0.0275])
    assert ds.model_path(13) == tmp_path / "models" / "obj_000013.ply"

    sc = ds.scene("test", 48)
    assert sc.image_ids() == [1, 2]
    np.testing.assert_allclose(sc.cameras[1].K[0], [1066.778, 0.0, 312.9869])
    assert sc.cameras[1].depth_scale == 0.1
    g = sc.gt[1][0]
    assert g.obj_id == 1
    np.testing.assert_allclose(g.t, [-0.0683, 0.0944, 0.8669])
    np.testing.assert_allclose(g.R, [[0, 1, 0], [0, 0, -1], [-1, 0, 0]])
    assert sc.gt[1][1].obj_id == 13 and len(sc.gt[2]) == 1
    gi = sc.gt_info[1][1]
    assert gi.bbox_visib == (380, 200, 150, 70) and gi.px_count_valid == 11900
    assert gi.visib_fract == pytest.approx(0.6166666666666667)

    rgb = sc.rgb(1)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].tolist() == [0, 0, 255]  # blue, now in RGB order
    d = sc.depth(2)
    assert d[1, 1] == pytest.approx(0.8669, abs=1e-6) and d[0, 0] == 0
    m = sc.mask_visib(1, 1)
    assert m.dtype == bool and m.sum() == 176 * 131


# --- bad input: typed errors, one line, naming the file ---------------------------------------


def _err(exc_type, fn, name: str):
    with pytest.raises(exc_type) as ei:
        fn()
    msg = str(ei.value)
    assert name in msg, msg
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('{"1": {"cam_K": [1, 0, 2, 0, 1', "invalid JSON"),
        ('{"1": {"depth_scale": 0.1}}', "cam_K"),
        ('{"1": {"cam_K": [1, 0, 2, 0, 1, 2, 0, 0], "depth_scale": 0.1}}', "9 numbers"),
        ('{"1": {"cam_K": [1, 0, 2, 0, "x", 2, 0, 0, 1], "depth_scale": 0.1}}', "9 numbers"),
        ('{"1": {"cam_K": [1, 0, 2, 0, 1, 2, 0, 0, 1], "depth_scale": "a"}}', "depth_scale"),
        ('{"one": {"cam_K": [1, 0, 2, 0, 1, 2, 0, 0, 1]}}', "'one'"),
        ("[1, 2]", "JSON object"),
    ],
)
def test_bad_scene_camera(tmp_path: Path, text: str, needle: str) -> None:
    sdir = _write_ycbv(tmp_path)
    (sdir / "scene_camera.json").write_text(text)
    msg = _err(BopFormatError, lambda: BopDataset(tmp_path).scene("test", 48), "scene_camera.json")
    assert needle in msg


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('{"1": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1]}]}', "obj_id"),
        ('{"1": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "obj_id": 1}]}', "cam_t_m2c"),
        ('{"1": [{"cam_R_m2c": [1, 0], "cam_t_m2c": [0, 0, 1], "obj_id": 1}]}', "cam_R_m2c"),
        (
            '{"1": [{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1], "obj_id": "a"}]}',
            "obj_id",
        ),
        ('{"1": {"obj_id": 1}}', "list"),
    ],
)
def test_bad_scene_gt(tmp_path: Path, text: str, needle: str) -> None:
    sdir = _write_ycbv(tmp_path)
    (sdir / "scene_gt.json").write_text(text)
    msg = _err(BopFormatError, lambda: BopDataset(tmp_path).scene("test", 48), "scene_gt.json")
    assert needle in msg


def test_bad_gt_info_and_models_info(tmp_path: Path) -> None:
    sdir = _write_ycbv(tmp_path)
    info = json.loads(YCBV_SCENE_GT_INFO)
    del info["1"][0]["px_count_visib"]
    (sdir / "scene_gt_info.json").write_text(json.dumps(info))
    msg = _err(BopFormatError, lambda: BopScene(sdir), "scene_gt_info.json")
    assert "px_count_visib" in msg
    info = json.loads(YCBV_SCENE_GT_INFO)
    info["1"].pop()
    (sdir / "scene_gt_info.json").write_text(json.dumps(info))
    _err(BopFormatError, lambda: BopScene(sdir), "scene_gt_info.json")

    mi = json.loads(YCBV_MODELS_INFO)
    del mi["13"]["diameter"]
    (tmp_path / "models" / "models_info.json").write_text(json.dumps(mi))
    msg = _err(BopFormatError, lambda: BopDataset(tmp_path).models_info(), "models_info.json")
    assert "diameter" in msg and "object 13" in msg
    mi = json.loads(YCBV_MODELS_INFO)
    mi["1"]["symmetries_discrete"][0].pop()
    (tmp_path / "models" / "models_info.json").write_text(json.dumps(mi))
    _err(BopFormatError, lambda: BopDataset(tmp_path).models_info(), "models_info.json")


def test_missing_files(tmp_path: Path) -> None:
    _err(DatasetError, lambda: BopDataset(tmp_path / "nope"), "nope")
    (tmp_path / "empty").mkdir()
    _err(DatasetError, lambda: BopDataset(tmp_path / "empty"), "empty")
    sdir = _write_ycbv(tmp_path / "ds")
    ds = BopDataset(tmp_path / "ds")
    _err(DatasetError, lambda: ds.scene_ids("val"), "val")
    _err(DatasetError, lambda: ds.scene("test", 7), "000007")
    _err(DatasetError, lambda: ds.load_object(13), "obj_000013.ply")
    _err(DatasetError, lambda: ds.load_object(99), "models_info.json")
    sc = ds.scene("test", 48)
    _err(DatasetError, lambda: sc.rgb(3), "scene_camera.json")
    (sdir / "rgb" / "000002.png").unlink()
    _err(DatasetError, lambda: sc.rgb(2), "000002.png")
    (sdir / "rgb" / "000001.png").write_bytes(b"not a png")
    _err(DatasetError, lambda: sc.rgb(1), "000001.png")
    _err(DatasetError, lambda: sc.mask_visib(1, 5), "000001_000005.png")
    (sdir / "depth" / "000002.png").unlink()
    assert sc.depth(2) is None
    (sdir / "scene_gt.json").unlink()
    assert BopScene(sdir).gt == {}
    (sdir / "scene_camera.json").unlink()
    _err(DatasetError, lambda: BopScene(sdir), "scene_camera.json")


def test_image_size_errors(tmp_path: Path) -> None:
    sdir = _write_ycbv(tmp_path)
    sc = BopScene(sdir)
    # rgb smaller than the principal point allows
    cv2.imwrite(str(sdir / "rgb" / "000001.png"), np.zeros((200, 300, 3), np.uint8))
    msg = _err(ImageSizeError, lambda: sc.rgb(1), "000001.png")
    assert "principal point" in msg
    # rgb containing the principal point but disagreeing with depth
    cv2.imwrite(str(sdir / "rgb" / "000002.png"), np.zeros((480, 641, 3), np.uint8))
    msg = _err(ImageSizeError, lambda: sc.rgb(2), "rgb/000002.png")
    assert "depth" in msg
    _err(ImageSizeError, lambda: sc.depth(2), "depth/000002.png")
    # mask disagreeing with rgb/depth
    cv2.imwrite(str(sdir / "mask_visib" / "000001_000000.png"), np.zeros((240, 320), np.uint8))
    _err(ImageSizeError, lambda: sc.mask_visib(1, 0), "000001_000000.png")
    # camera with an explicit size
    cams = {1: CameraInfo(K, 0.1, width=W + 1, height=H)}
    bop.write_scene_camera(sdir / "scene_camera.json", cams)
    bop.write_rgb(sdir / "rgb" / "000001.png", np.zeros((H, W, 3), np.uint8))
    bop.write_depth(sdir / "depth" / "000001.png", np.ones((H, W)))
    msg = _err(ImageSizeError, lambda: BopScene(sdir).rgb(1), "000001.png")
    assert f"{W + 1}x{H}" in msg


def test_image_size_header(tmp_path: Path) -> None:
    img = np.zeros((37, 53, 3), np.uint8)
    for ext in (".png", ".jpg"):
        p = tmp_path / f"a{ext}"
        bop.write_rgb(p, img)
        assert bop.image_size(p) == (37, 53)
    assert bop.image_size(tmp_path / "missing.png") is None


def test_writers_reject_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        bop.write_rgb(tmp_path / "a.png", np.zeros((4, 4), np.uint8))
    with pytest.raises(DatasetError, match=r"uint16 .* \(at most 6\.55 m; raise depth"):
        bop.write_depth(tmp_path / "d.png", np.full((4, 4), 10.0), depth_scale=0.1)
    bop.write_depth(tmp_path / "d.png", np.full((4, 4), 10.0), depth_scale=1.0)
    assert not list(tmp_path.glob(".*tmp"))


def test_load_object_from_models_info(tmp_path: Path) -> None:
    import trimesh

    _write_ycbv(tmp_path)
    trimesh.creation.box(extents=[102.289, 102.289, 140.376]).export(
        tmp_path / "models" / "obj_000001.ply"
    )
    obj = BopDataset(tmp_path).load_object(1)
    assert obj.obj_id == 1
    np.testing.assert_allclose(obj.mesh.extents, [0.102289, 0.102289, 0.140376], rtol=1e-6)
    assert np.abs(obj.points).max() < 0.08  # metres
    assert obj.diameter == pytest.approx(0.172063)  # models_info wins over the mesh
    np.testing.assert_allclose(obj.symmetries_discrete[0], np.diag([-1.0, -1, 1, 1]))
    info = bop.model_info_from_object(obj)
    np.testing.assert_allclose(info.size_xyz, [0.102289, 0.102289, 0.140376], rtol=1e-6)
    np.testing.assert_allclose(info.min_xyz, -info.size_xyz / 2, atol=1e-9)
