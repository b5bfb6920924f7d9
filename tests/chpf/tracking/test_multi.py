"""Several objects at once: the MultiTracker API and chpf-track --bundle repeated, with the
shipped bundle on the shipped demo's first frames (N = 10 particles: fast, not accurate)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import chpf.tracking
from chpf.bop import read_results_csv, read_rgb
from chpf.bundle import Bundle
from chpf.errors import ConfigError
from chpf.track_cli import cli, main
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.multi import MultiTracker
from chpf.tracking.runlog import read_log
from chpf.tracking.tracker import Tracker
from tests.helpers import (
    DEMO_K,
    DEMO_ROOT,
    DEMO_SCENE,
    PLAIN_FRAMES,
    console_error,
    count_video_frames,
    demo_box,
    demo_frames,
)

N = PLAIN_FRAMES  # frames of the images fixture (conftest)
FAST = ["--n-particles", "10", "--no-progress", "--no-plot"]
TWIN = 9  # obj_id of the second copy of the demo's box in the two-object dataset


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    return Bundle.load(shipped_bundle())


def _box(im_id: int = 1, dx: float = 0.0) -> str:
    b = demo_box(im_id)
    return ",".join(f"{v:g}" for v in (b[0] + dx, *b[1:]))


def _run(capsys, *argv) -> list[str]:
    code = main([str(a) for a in argv] + FAST)
    assert code == 0
    return capsys.readouterr().out.splitlines()


def _poses(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def two_object_dataset(tmp_path, n: int = N):
    """The demo dataset cut to its first n frames, with a second object TWIN: a copy of the box
    (obj_id 2) at the same poses, with its own model file and models_info entry."""
    root = tmp_path / "two"
    models = root / "models"
    shutil.copytree(DEMO_ROOT / "models", models)
    shutil.copy(models / "obj_000002.ply", models / f"obj_{TWIN:06d}.ply")
    info = json.loads((models / "models_info.json").read_text())
    info[str(TWIN)] = info["2"]
    (models / "models_info.json").write_text(json.dumps(info))
    scene = root / "test" / "000001"
    (scene / "rgb").mkdir(parents=True)
    for f in demo_frames(n):
        shutil.copy(f, scene / "rgb")
    cams = json.loads((DEMO_SCENE / "scene_camera.json").read_text())
    gt = json.loads((DEMO_SCENE / "scene_gt.json").read_text())
    gt_info = json.loads((DEMO_SCENE / "scene_gt_info.json").read_text())
    keep = [k for k in gt if int(k) <= n]
    for k in keep:
        i = next(j for j, g in enumerate(gt[k]) if g["obj_id"] == 2)
        gt[k].append({**gt[k][i], "obj_id": TWIN})
        gt_info[k].append(gt_info[k][i])
    for name, data in (("scene_camera", cams), ("scene_gt", gt), ("scene_gt_info", gt_info)):
        (scene / f"{name}.json").write_text(json.dumps({k: data[k] for k in keep}))
    return root


# --- the Python API ---------------------------------------------------------------------------


def test_multitracker_steps_every_object_as_lone_trackers_would(bundle):
    rgb = [read_rgb(f) for f in demo_frames(3)]
    box = tuple(demo_box(1))
    other = (20.0, 60.0, 60.0, 80.0)
    cfg = {"filter": {"n_particles": 10}}
    lone = [Tracker(bundle, seed=3, config=cfg) for _ in range(2)]
    two = MultiTracker([Tracker(bundle, seed=3, config=cfg) for _ in range(2)], [2, 5])
    for i, img in enumerate(rgb):
        boxes = [box, other] if i == 0 else [None, None]
        alone = [t.step(img, K=DEMO_K, box=b) for t, b in zip(lone, boxes, strict=True)]
        together = two.step(img, K=DEMO_K, boxes=boxes)
        for a, b in zip(alone, together, strict=True):  # each object: a lone tracker's poses
            np.testing.assert_array_equal(a.t, b.t)
            np.testing.assert_array_equal(a.R, b.R)
    assert not np.array_equal(together[0].t, together[1].t)

    multi = MultiTracker.from_bundles(
        [bundle, bundle], obj_ids=[2, 5], n_particles=10, config=None, seed=3
    )
    assert multi.obj_ids == [2, 5] and len(multi) == 2
    assert chpf.tracking.MultiTracker is MultiTracker
    assert multi.trackers[0].bundle is multi.trackers[1].bundle  # loaded once
    out = multi.step(rgb[0], K=DEMO_K, boxes={5: box})
    assert len(out) == 2 and [r.ok for r in out] == [False, True]  # no box, no state for 2
    out = multi.step(rgb[1], K=DEMO_K)  # no boxes at all
    assert len(out) == 2 and len(multi.last_ms) == 2 and min(multi.last_ms) > 0
    with pytest.raises(ConfigError, match="1 boxes for 2 objects"):
        multi.step(rgb[2], K=DEMO_K, boxes=[box])
    with pytest.raises(ConfigError, match=r"obj_id\(s\) \[7\]"):
        multi.step(rgb[2], K=DEMO_K, boxes={7: box})
    with pytest.raises(ConfigError, match=r"obj_id\(s\) \[2\] given to more than one"):
        MultiTracker(lone)


# --- chpf-track --bundle A --bundle B --------------------------------------------------------


def test_two_bundles_on_bop_data_track_each_obj_id_with_per_object_outputs(tmp_path, capsys):
    root = two_object_dataset(tmp_path)
    out = tmp_path / "out"
    s = shipped_bundle()
    argv = [
        *("--bundle", s, "--bundle", s, "--obj-id", 2, "--obj-id", TWIN),
        *("--dataset", root, "--out", out, "--method", "chpf,srl"),
    ]
    lines = _run(capsys, *argv, "--poses", out / "p.jsonl", "--overlay", out / "o.avi")
    assert f"tracking obj_id 2 (box) and obj_id {TWIN} (box)" in lines[1]
    rows = read_results_csv(out / "chpf_two-test.csv")  # one CSV per method, all objects
    assert sorted(r.key for r in rows) == sorted(
        (1, i, o) for i in range(1, N + 1) for o in (2, TWIN)
    )
    for m in ("chpf", "srl"):
        for o in (2, TWIN):
            log = read_log(out / f"log_{m}_obj{o}.csv")
            assert [(r.scene_id, r.im_id, r.obj_id) for r in log] == [
                (1, i, o) for i in range(1, N + 1)
            ]
            assert all(np.isfinite(r.values["err_adds"]) for r in log)  # each its ground truth
    assert not (out / "log_chpf.csv").exists()
    table = (out / "auc_table.txt").read_text()
    for label in ("chpf obj 2", f"chpf obj {TWIN}", "srl obj 2", f"srl obj {TWIN}"):
        assert label in table
    runs = json.loads((out / "runs.json").read_text())
    assert runs[f"srl obj {TWIN}"]["obj_id"] == TWIN
    poses = _poses(out / "p.jsonl")  # one line per frame, method and object
    assert [(d["frame"], d["method"], d["obj_id"]) for d in poses] == [
        (i, m, o) for i in range(1, N + 1) for m in ("chpf", "srl") for o in (2, TWIN)
    ]
    assert count_video_frames(out / "o_chpf.avi") == N  # both objects on each frame

    # obj 2 tracked alone gives the same poses as with TWIN beside it (boxes and seeds per object)
    alone = tmp_path / "alone"
    _run(capsys, "--bundle", s, "--dataset", root, "--out", alone, "--method", "chpf,srl")
    for m in ("chpf", "srl"):
        lone = read_results_csv(alone / f"{m}_two-test.csv")
        both = [r for r in read_results_csv(out / f"{m}_two-test.csv") if r.obj_id == 2]
        assert [r.key for r in lone] == [r.key for r in both]
        for a, b in zip(lone, both, strict=True):
            np.testing.assert_allclose(a.t, b.t, atol=1e-9)
            np.testing.assert_allclose(a.R, b.R, atol=1e-9)

    # a rerun with the same settings resumes: nothing new in the CSVs or the logs
    _run(capsys, *argv)
    assert len(read_results_csv(out / "chpf_two-test.csv")) == 2 * N
    assert len(read_log(out / f"log_srl_obj{TWIN}.csv")) == N


def test_bop_refusals_name_the_bundle_and_the_rule(tmp_path, capsys, monkeypatch):
    root = two_object_dataset(tmp_path)
    s = shipped_bundle()
    base = ["--bundle", s, "--bundle", s, "--dataset", root, "--out", tmp_path / "o"]
    line = console_error(cli, capsys, monkeypatch, *base)
    assert "obj_id 2 is tracked by more than one --bundle" in line and "--obj-id" in line
    line = console_error(cli, capsys, monkeypatch, *base, "--obj-id", "2")
    assert "--obj-id given 1 time(s) for 2 --bundle" in line
    line = console_error(cli, capsys, monkeypatch, *base, "--obj-id", "2", "--obj-id", "8")
    assert "pass --obj-id N" in line and "[1, 2, 4, 9]" in line
    line = console_error(cli, capsys, monkeypatch, "--demo", "--bundle", s, "--bundle", s)
    assert "--demo tracks one object" in line
    assert not (tmp_path / "o").exists()


def test_image_folder_with_one_init_box_per_bundle_reads_each_frame_once(
    images, camera, tmp_path, capsys, monkeypatch
):
    import chpf.sources.images as images_mod

    reads = []
    real = images_mod.read_rgb
    monkeypatch.setattr(images_mod, "read_rgb", lambda p: reads.append(p) or real(p))
    out = tmp_path / "out"
    s = shipped_bundle()
    lines = _run(
        capsys,
        *("--bundle", s, "--bundle", s, "--obj-id", 1, "--obj-id", 2),
        *("--images", images, "--camera", camera, "--out", out, "--method", "chpf,poserbpf"),
        *("--init-box", _box(), "--init-box", _box(dx=-20.0)),
        *("--poses", out / "p.jsonl", "--overlay", out / "png"),
    )
    assert len(reads) == N  # two objects, two methods: each frame read once
    assert lines[0].startswith(f"detections: --init-box {_box()} {_box(dx=-20.0)} on the first")
    rows = read_results_csv(out / "chpf_rgb-images.csv")
    assert sorted(r.key for r in rows) == sorted((1, i, o) for i in range(1, N + 1) for o in (1, 2))
    for o in (1, 2):
        log = read_log(out / f"log_poserbpf_obj{o}.csv")
        assert [int(r.values["has_box"]) for r in log] == [1, 0, 0, 0]
    poses = _poses(out / "p.jsonl")
    assert len(poses) == N * 2 * 2
    assert {(d["obj_id"], d["object"]) for d in poses} == {(1, "box"), (2, "box")}
    assert [d["has_box"] for d in poses if d["method"] == "chpf"] == [True, True] + [False] * 6
    pngs = sorted((out / "png" / "chpf").glob("*.png"))
    assert len(pngs) == N  # one overlay frame per frame, both objects drawn on it
    settings = json.loads((out / "track_settings.json").read_text())
    assert len(settings["bundles"]) == 2 and settings["obj_ids"] == [1, 2]
    assert len(settings["init_box"]) == 2


def test_init_box_count_must_match_the_bundles(images, camera, tmp_path, capsys, monkeypatch):
    s = shipped_bundle()
    base = ["--bundle", s, "--bundle", s, "--obj-id", "1", "--obj-id", "2"]
    base += ["--images", str(images), "--camera", str(camera), "--out", str(tmp_path / "o")]
    line = console_error(cli, capsys, monkeypatch, *base, "--init-box", _box())
    assert line == (
        "error: --init-box given 1 time(s) for 2 --bundle: give one box per --bundle, in the "
        "same order"
    )
    three = ["--init-box", _box(), "--init-box", _box(), "--init-box", _box()]
    line = console_error(cli, capsys, monkeypatch, *base, *three)
    assert "given 3 time(s) for 2 --bundle" in line
    dets = tmp_path / "boxes.csv"
    dets.write_text(f"frame,x,y,w,h\n1,{_box()}\n")
    line = console_error(cli, capsys, monkeypatch, *base, "--detections", str(dets))
    assert str(dets) in line and "no object column" in line
    assert not (tmp_path / "o").exists()
