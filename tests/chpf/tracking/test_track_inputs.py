"""chpf-track on plain inputs (image folders, videos) and its --overlay / --poses outputs, with
the shipped bundle on the shipped demo's first frames (N = 10: fast, not accurate)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from chpf.bop import read_results_csv
from chpf.track_cli import cli, main
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.runlog import read_log
from chpf.tracking.warn import SkippedFrameWarning
from tests.helpers import (
    DEMO_K,
    DEMO_ROOT,
    DEMO_SCENE,
    PLAIN_FRAMES,
    console_error,
    count_video_frames,
    demo_box,
    demo_frames,
    write_video,
)

N = PLAIN_FRAMES  # frames of the images fixture (conftest)
FAST = ["--n-particles", "10", "--no-progress", "--no-plot"]


def _box() -> str:
    return ",".join(f"{v:g}" for v in demo_box(1))


def _run(capsys, *argv) -> list[str]:
    code = main([str(a) for a in ["--bundle", shipped_bundle(), *argv, *FAST]])
    assert code == 0
    return capsys.readouterr().out.splitlines()


def _poses(path, drop: tuple[str, ...] = ()) -> list[dict]:
    """The JSON lines of a --poses file (without the keys ``drop``)."""
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    return [{k: v for k, v in d.items() if k not in drop} for d in lines]


def _check_pose_lines(lines: list[dict], frames: list[int], methods: list[str]) -> None:
    assert [(d["frame"], d["method"]) for d in lines] == [(f, m) for f in frames for m in methods]
    for d in lines:
        assert d["obj_id"] == 2 and d["object"] == "box" and d["ok"] is True
        R = np.array(d["R"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-6)
        assert np.linalg.det(R) > 0 and len(d["t"]) == 3 and 0.1 < d["t"][2] < 5.0


def test_image_folder_with_init_box_writes_results_overlay_video_and_poses(
    images, camera, tmp_path, capsys
):
    out = tmp_path / "out"
    lines = _run(
        capsys,
        *("--images", images, "--camera", camera, "--init-box", _box(), "--out", out),
        *("--overlay", out / "overlay.mp4", "--poses", out / "poses.jsonl"),
    )
    assert lines[0].startswith("detections: --init-box") and "first frame only" in lines[0]
    assert "(4 frames, 320x240)" in lines[1]
    assert any("no ground truth" in line and "no AUC table" in line for line in lines)
    assert not (out / "auc_table.txt").exists()
    rows = read_results_csv(out / "chpf_rgb-images.csv")
    assert [r.key for r in rows] == [(1, i, 2) for i in range(1, N + 1)]
    log = read_log(out / "log_chpf.csv")
    assert [int(r.values["has_box"]) for r in log] == [1, 0, 0, 0]
    assert count_video_frames(out / "overlay.mp4") == N
    assert not list(out.glob(".overlay*"))  # the temporary video was moved into place
    poses = _poses(out / "poses.jsonl")
    _check_pose_lines(poses, list(range(1, N + 1)), ["chpf"])
    assert [d["has_box"] for d in poses] == [True, False, False, False]
    np.testing.assert_allclose([d["time"] for d in poses], np.arange(N) / 30.0, atol=1e-6)
    for d, r in zip(poses, rows, strict=True):  # the same poses as the result CSV (mm there)
        np.testing.assert_allclose(np.array(d["t"]) * 1000.0, r.t * 1000.0, atol=1e-3)


def test_video_with_csv_detections_and_png_overlay_of_two_methods(tmp_path, camera, capsys):
    video = write_video(tmp_path / "clip.mp4", demo_frames(N), fps=15.0)
    dets = tmp_path / "boxes.csv"
    dets.write_text("frame,x,y,w,h\n" + "".join(f"{i},{_box()}\n" for i in (0, 2)))
    out = tmp_path / "out"
    _run(
        capsys,
        *("--video", video, "--camera", camera, "--detections", dets, "--out", out),
        *("--method", "chpf,poserbpf", "--overlay", out / "png", "--poses", out / "p.jsonl"),
    )
    for m in ("chpf", "poserbpf"):
        pngs = sorted((out / "png" / m).glob("*.png"))
        assert [p.name for p in pngs] == [f"000001_{i:06d}.png" for i in range(N)]
        log = read_log(out / f"log_{m}.csv")
        assert [int(r.values["has_box"]) for r in log] == [1, 0, 1, 0]
    assert (out / "chpf_clip-video.csv").is_file()
    poses = _poses(out / "p.jsonl")
    _check_pose_lines(poses, list(range(N)), ["chpf", "poserbpf"])
    np.testing.assert_allclose(poses[2]["time"], 1 / 15.0, atol=1e-6)  # the video's own fps


def _mini_demo(tmp_path, n: int):
    """The demo dataset cut to its first n frames."""
    root = tmp_path / "mini"
    shutil.copytree(DEMO_ROOT / "models", root / "models")
    scene = root / "test" / "000001"
    (scene / "rgb").mkdir(parents=True)
    for f in demo_frames(n):
        shutil.copy(f, scene / "rgb")
    for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json"):
        data = json.loads((DEMO_SCENE / name).read_text())
        (scene / name).write_text(json.dumps({k: v for k, v in data.items() if int(k) <= n}))
    return root


def test_bop_dataset_run_writes_overlay_and_poses_and_retracks_for_them(tmp_path, capsys):
    root = _mini_demo(tmp_path, N)
    out = tmp_path / "out"
    argv = ["--dataset", root, "--out", out, "--poses", out / "p.jsonl"]
    lines = _run(capsys, *argv, "--overlay", out / "o.avi")
    assert any("ADD-S AUC" in line for line in lines)
    assert count_video_frames(out / "o.avi") == N
    _check_pose_lines(_poses(out / "p.jsonl"), list(range(1, N + 1)), ["chpf"])
    first = _poses(out / "p.jsonl", drop=("ms",))
    # a rerun with the same settings has nothing left to write to the CSV, but tracks every
    # frame again for its --poses (the same poses: each scene's filter is seeded)
    _run(capsys, *argv)
    assert len(read_results_csv(out / "chpf_mini-test.csv")) == N
    assert _poses(out / "p.jsonl", drop=("ms",)) == first


def test_unreadable_frames_are_skipped_and_the_outputs_stay_valid(images, camera, tmp_path, capsys):
    (images / "000003.png").write_bytes(b"\x89PNG broken")
    out = tmp_path / "out"
    with pytest.warns(SkippedFrameWarning, match=r"000003\.png.*skipped"):
        _run(
            capsys,
            *("--images", images, "--camera", camera, "--init-box", _box(), "--out", out),
            *("--overlay", out / "o.mp4", "--poses", out / "p.jsonl"),
        )
    assert [r.key[1] for r in read_results_csv(out / "chpf_rgb-images.csv")] == [1, 2, 4]
    assert count_video_frames(out / "o.mp4") == 3
    _check_pose_lines(_poses(out / "p.jsonl"), [1, 2, 4], ["chpf"])


def test_bad_plain_inputs_exit_2_with_one_line_naming_the_file(
    images, camera, tmp_path, capsys, monkeypatch
):
    base = ["--bundle", shipped_bundle(), "--out", tmp_path / "o"]

    def refused(*argv) -> str:
        return console_error(cli, capsys, monkeypatch, *base, *argv)

    ok = ["--camera", camera, "--init-box", _box()]
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"K": DEMO_K.tolist(), "width": 640, "height": 480}))
    line = refused("--images", images, "--camera", wrong, "--init-box", _box())
    assert str(wrong) in line and "640x480" in line and "320x240" in line

    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("focal_length: 300\n")
    line = refused("--images", images, "--camera", unknown, "--init-box", _box())
    assert str(unknown) in line and "unknown camera file layout" in line

    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00" * 1000)
    line = refused("--video", junk, *ok)
    assert str(junk) in line and "cannot open the video" in line

    mixed = tmp_path / "mixed"
    shutil.copytree(images, mixed)
    import cv2

    cv2.imwrite(str(mixed / "000002.png"), np.zeros((120, 160, 3), np.uint8))
    line = refused("--images", mixed, *ok)
    assert str(mixed) in line and "mixed sizes" in line

    empty = tmp_path / "empty"
    empty.mkdir()
    line = refused("--images", empty, *ok)
    assert str(empty) in line and "no image files" in line

    line = refused("--images", images, "--camera", camera, "--init-box", "330,10,20,20")
    assert "000001.png" in line and "--init-box 330,10,20,20 lies outside" in line

    depth = tmp_path / "depth"
    depth.mkdir()
    cv2.imwrite(str(depth / "000001.png"), np.zeros((240, 320), np.uint16))
    line = refused("--images", images, "--depth", depth, *ok, "--modality", "rgbd")
    assert str(depth) in line and "1 depth images but 4 images" in line

    line = refused("--images", images, "--camera", camera)
    assert "--init-box" in line and "--detections" in line
    line = refused("--images", images, "--init-box", _box())
    assert "--camera" in line
    line = refused("--dataset", DEMO_ROOT, "--camera", camera)
    assert "only with --images or --video" in line
    line = refused("--images", images, *ok, "--overlay", tmp_path / "o.gif")
    assert "o.gif" in line and "video" in line
