"""sequences command: BOP layout, agreement of images with the stored poses, detections."""

from __future__ import annotations

import json

import numpy as np
import pytest

from chpf.bop import BopDataset, read_detections
from chpf.errors import DatasetError
from chpf.render import Renderer
from data_gen import cli

ARGS = [
    "--num-scenes",
    "1",
    "--frames",
    "6",
    "--width",
    "320",
    "--height",
    "240",
    "--set",
    "sequences.focal=300",
    "--no-progress",
]


def _sequences(out, occlusion: str = "heavy") -> int:
    """Run the ``sequences`` command (mug target, can distractor, seed 3) into ``out``."""
    args = ["--objects", "mug,can", "--out", str(out), "--occlusion", occlusion, "--seed", "3"]
    return cli.main(["sequences", *args, *ARGS])


@pytest.fixture(scope="module")
def seq_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq") / "bop"
    assert _sequences(root) == 0
    return root


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_bop_files_read_back(seq_root):
    ds = BopDataset(seq_root)
    infos = ds.models_info()
    assert sorted(infos) == [1, 2, 3]  # mug target, can distractor, box occluder
    assert len(infos[3].symmetries_continuous) == 1 and not infos[1].symmetries_continuous
    mug = ds.load_object(1)
    from chpf.objects import builtin_object

    assert mug.diameter == pytest.approx(builtin_object("mug").diameter, rel=1e-3)
    assert ds.scene_ids("test") == [1]
    scene = ds.scene("test", 1)
    assert scene.image_ids() == [1, 2, 3, 4, 5, 6]
    cam = scene.cameras[1]
    assert cam.R_w2c is not None and cam.depth_scale == pytest.approx(0.1)
    assert [g.obj_id for g in scene.gt[1]] == [1, 3, 2]
    info = json.loads((seq_root / "sequences_info.json").read_text())
    assert info["objects"][0]["role"] == "target" and info["scenes"][0]["frames"] == 6


def test_masks_and_depth_agree_with_gt_poses(seq_root):
    ds = BopDataset(seq_root)
    scene = ds.scene("test", 1)
    objs = {i: ds.load_object(i) for i in ds.models_info()}
    ren = Renderer(320, 240)
    for im in scene.image_ids():
        gts = scene.gt[im]
        out = ren.render([(objs[g.obj_id], g.R, g.t) for g in gts], scene.cameras[im].K)
        depth = scene.depth(im)
        for k in range(len(gts)):
            m, mv = scene.mask(im, k), scene.mask_visib(im, k)
            info = scene.gt_info[im][k]
            if out.masks[k].any():
                assert _iou(m, out.masks[k]) > 0.97
            if mv.sum() > 20:
                assert _iou(mv, out.visible_masks[k]) > 0.95
            assert info.px_count_all == m.sum() and info.px_count_visib == mv.sum()
            if m.sum():
                assert info.visib_fract == pytest.approx(mv.sum() / m.sum(), abs=1e-6)
        # stored depth = rendered depth + simulated sensor noise (and a few holes)
        vis0 = out.visible_masks[0] & (depth > 0)
        if vis0.sum() > 20:
            err = np.abs(depth[vis0] - out.depth[vis0])
            assert np.median(err) < 0.004 and np.mean(err < 0.02) > 0.95
    rgb = scene.rgb(1)
    assert rgb.shape == (240, 320, 3) and rgb.std() > 10


def test_heavy_occlusion_is_recorded(seq_root):
    info = json.loads((seq_root / "sequences_info.json").read_text())
    ds = BopDataset(seq_root)
    scene = ds.scene("test", 1)
    v = np.array([scene.gt_info[im][0].visib_fract for im in scene.image_ids()])
    assert v.min() < 0.5 and v.max() > 0.9
    assert info["scenes"][0]["target_visib_fract"]["min"] == pytest.approx(v.min(), abs=1e-4)


def test_simulated_detections(seq_root):
    dets = read_detections(seq_root / "detections_sim.json")
    scene = BopDataset(seq_root).scene("test", 1)
    hits = 0
    for im in scene.image_ids():
        info = scene.gt_info[im][0]
        box = dets.get((1, im, 1))
        if info.visib_fract < 0.1:
            assert box is None
        if box is not None:
            hits += 1
            x, y, w, h = info.bbox_visib
            bx, by, bw, bh = box
            assert abs((bx + bw / 2) - (x + w / 2)) < 0.5 * w + 3
            assert abs((by + bh / 2) - (y + h / 2)) < 0.5 * h + 3
            assert 0.5 < bw / max(w, 1) < 2.0
            assert 0 <= bx and bx + bw <= 320 and 0 <= by and by + bh <= 240
    assert hits >= 2


def test_rerun_resumes_and_refuses_other_settings(seq_root, tmp_path):
    before = {p: p.read_bytes() for p in seq_root.rglob("*") if p.is_file()}
    assert _sequences(seq_root) == 0
    after = {p: p.read_bytes() for p in seq_root.rglob("*") if p.is_file()}
    assert before == after
    with pytest.raises(DatasetError):
        _sequences(seq_root, occlusion="none")
    # same seed -> same bytes in a fresh folder
    other = tmp_path / "again"
    assert _sequences(other) == 0
    for p, data in before.items():
        assert (other / p.relative_to(seq_root)).read_bytes() == data


def test_contact_sheet_of_sequence(seq_root, tmp_path):
    import cv2

    png = tmp_path / "seq.png"
    assert cli.main(["contact-sheet", str(seq_root), "--out", str(png), "--n", "4"]) == 0
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] > 4 * 160


def test_mesh_in_millimetres_given_as_metres_is_refused(tmp_path, capsys):
    """A mm mesh with --unit m (a 319.7 m box, rendered 643 m away) exits 2 in one line naming
    --unit mm, before anything is written; --allow-size accepts it."""
    import sys

    from chpf.objects import get_object

    mesh = get_object("box").mesh.copy()
    mesh.apply_scale(1000.0)
    path = tmp_path / "box_mm.ply"
    mesh.export(path)
    out = tmp_path / "seq"
    argv = ["chpf-gen-data", "sequences", "--objects", str(path), "--unit", "m", "--out", str(out)]
    saved = sys.argv
    sys.argv = [*argv, *ARGS]
    try:
        with pytest.raises(SystemExit) as exc:
            cli.cli()
    finally:
        sys.argv = saved
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1, err
    assert "diameter 319.7 m" in err[0] and "--unit mm" in err[0]
    assert not out.exists() or not any(p.name != ".seq.chpf.lock" for p in out.iterdir())
    args = ["--objects", str(path), "--unit", "mm", "--out", str(out), *ARGS]
    assert cli.main(["sequences", *args]) == 0
    with pytest.raises(SystemExit):  # argparse: --allow-size is a known flag, --unit cm too
        cli.main(["sequences", "--objects", str(path), "--unit", "km", "--out", str(out)])
    assert (
        cli.build_parser()
        .parse_args(
            ["ae", "--object", "x", "--out", "o", "--n", "1", "--allow-size", "--unit", "cm"]
        )
        .allow_size
    )
