"""Image folders, videos and per-frame boxes as chpf-track inputs (chpf.sources), on the
shipped demo's frames."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from chpf.bop import read_rgb, write_depth
from chpf.errors import SourceError
from chpf.sources.boxes import PlainBoxes, check_init_box, parse_box, read_frame_boxes
from chpf.sources.camera import Camera
from chpf.sources.images import ImageFolder
from chpf.sources.video import VideoFile
from chpf.tracking.warn import SkippedFrameWarning
from tests.helpers import DEMO_K, demo_frames, write_video

CAM = Camera(path=Path("cam.json"), K=DEMO_K, width=320, height=240)
BOX = (110.0, 46.0, 93.0, 133.0)


def _folder(tmp_path, n: int, names=None):
    folder = tmp_path / "rgb"
    folder.mkdir()
    for i, src in enumerate(demo_frames(n)):
        shutil.copy(src, folder / (names[i] if names else src.name))
    return folder


def _read_all(source):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(source)
    return frames, [str(w.message) for w in caught if w.category is SkippedFrameWarning]


def test_image_folder_yields_numbered_frames_with_k_box_and_time(tmp_path):
    folder = _folder(tmp_path, 4)
    src = ImageFolder(folder, CAM, PlainBoxes(init=BOX), fps=10.0)
    assert src.frame_ids() == [1, 2, 3, 4] and (src.width, src.height) == (320, 240)
    frames, warned = _read_all(src)
    assert not warned and [f.index for f in frames] == [1, 2, 3, 4]
    assert [f.box for f in frames] == [BOX, None, None, None]
    np.testing.assert_allclose([f.time for f in frames], [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(frames[2].rgb, read_rgb(demo_frames(3)[2]))
    assert frames[0].depth is None and frames[0].K is DEMO_K


def test_names_that_are_not_all_numbers_sort_naturally_and_count_from_0(tmp_path):
    folder = _folder(tmp_path, 3, names=["frame10.png", "frame2.png", "frame9.jpg"])
    src = ImageFolder(folder, CAM, PlainBoxes({0: BOX, 2: BOX}), fps=30.0)
    assert [p.name for p in src.files] == ["frame2.png", "frame9.jpg", "frame10.png"]
    frames, _ = _read_all(src)
    assert [f.index for f in frames] == [0, 1, 2] and [f.box for f in frames] == [BOX, None, BOX]


def test_depth_folder_is_read_with_its_scale(tmp_path):
    folder = _folder(tmp_path, 2)
    depth = tmp_path / "depth"
    for i in (1, 2):
        write_depth(depth / f"{i:06d}.png", np.full((240, 320), 0.5 * i), depth_scale=0.1)
    frames, _ = _read_all(
        ImageFolder(folder, CAM, PlainBoxes(init=BOX), 30.0, depth=depth, depth_scale=0.1)
    )
    np.testing.assert_allclose([f.depth.mean() for f in frames], [0.5, 1.0], atol=1e-4)
    (depth / "000002.png").unlink()
    with pytest.raises(SourceError, match=r"depth: 1 depth images but 2 images in .*rgb"):
        ImageFolder(folder, CAM, PlainBoxes(), 30.0, depth=depth)


def test_folder_refusals_name_the_folder(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("x")
    with pytest.raises(SourceError, match=r"empty: no image files"):
        ImageFolder(empty, CAM, PlainBoxes(), 30.0)
    with pytest.raises(SourceError, match="folder not found"):
        ImageFolder(tmp_path / "none", CAM, PlainBoxes(), 30.0)
    folder = _folder(tmp_path, 3)
    small = cv2.resize(cv2.imread(str(folder / "000002.png")), (160, 120))
    cv2.imwrite(str(folder / "000002.png"), small)
    with pytest.raises(SourceError, match=r"rgb: images of mixed sizes .*000002.png is 160x120"):
        ImageFolder(folder, CAM, PlainBoxes(), 30.0)


def test_corrupt_image_in_the_middle_is_skipped_with_one_warning(tmp_path):
    folder = _folder(tmp_path, 5)
    for name in ("000002.png", "000004.png"):
        (folder / name).write_bytes(b"not a png at all")
    frames, warned = _read_all(ImageFolder(folder, CAM, PlainBoxes(init=BOX), 30.0))
    assert [f.index for f in frames] == [1, 3, 5]
    assert len(warned) == 1 and "000002.png" in warned[0] and "skipped" in warned[0]


def test_video_written_with_opencv_yields_its_frames(tmp_path):
    path = write_video(tmp_path / "clip.mp4", demo_frames(5), fps=12.0)
    src = VideoFile(path, CAM, PlainBoxes(init=BOX), fps=30.0)
    assert src.frame_ids() == [0, 1, 2, 3, 4] and src.fps == 12.0
    frames, warned = _read_all(src)
    assert not warned and [f.index for f in frames] == [0, 1, 2, 3, 4]
    assert [f.box for f in frames] == [BOX, None, None, None, None]
    np.testing.assert_allclose(frames[3].time, 3 / 12.0)
    original = read_rgb(demo_frames(5)[4]).astype(np.float64)
    assert np.abs(frames[4].rgb - original).mean() < 6.0  # mp4v is lossy, but it is frame 4


def _mjpeg_video(tmp_path, n: int):
    path = write_video(tmp_path / "clip.avi", demo_frames(n), fourcc="MJPG")
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 2) if data[i : i + 3] == b"\xff\xd8\xff"]
    assert len(starts) == n
    return path, data, starts


def test_video_that_ends_early_stops_with_a_warning(tmp_path):
    path, data, starts = _mjpeg_video(tmp_path, 6)
    path.write_bytes(bytes(data[: starts[4]]))  # frames 4 and 5 cut off; the header says 6
    src = VideoFile(path, CAM, PlainBoxes(init=BOX), 30.0)
    assert src.frame_ids() == list(range(6))
    frames, warned = _read_all(src)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert len(warned) == 1 and "ends at frame 4 of the 6" in warned[0]


def test_corrupt_video_frame_in_the_middle_is_skipped(tmp_path):
    path, data, starts = _mjpeg_video(tmp_path, 6)
    data[starts[2] : starts[2] + 2000] = bytes(2000)
    path.write_bytes(bytes(data))
    frames, warned = _read_all(VideoFile(path, CAM, PlainBoxes(), 30.0))
    assert [f.index for f in frames] == [0, 1, 3, 4, 5]
    assert len(warned) == 1 and "frame 2 unreadable" in warned[0]
    original = read_rgb(demo_frames(4)[3]).astype(np.float64)
    assert np.abs(frames[2].rgb - original).mean() < 6.0  # frame 3 is frame 3


def test_unreadable_videos_are_refused_naming_the_file(tmp_path):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"no video here" * 100)
    with pytest.raises(SourceError, match=r"junk\.mp4: cannot open the video"):
        VideoFile(junk, CAM, PlainBoxes(), 30.0)
    with pytest.raises(SourceError, match="video file not found"):
        VideoFile(tmp_path / "none.mp4", CAM, PlainBoxes(), 30.0)
    wrong = Camera(path=tmp_path / "cam.json", K=DEMO_K, width=640, height=480)
    with pytest.raises(SourceError, match=r"cam.json: camera file says 640x480 .* 320x240"):
        VideoFile(write_video(tmp_path / "ok.mp4", demo_frames(2)), wrong, PlainBoxes(), 30.0)


def test_detections_csv_and_json_by_frame(tmp_path):
    csv = tmp_path / "dets.csv"
    csv.write_text("frame,x,y,w,h,score\n0,1,2,3,4,0.5\n0,5,6,7,8,0.9\n3,1,1,9,9\n\n")
    assert read_frame_boxes(csv, 2) == {0: (5.0, 6.0, 7.0, 8.0), 3: (1.0, 1.0, 9.0, 9.0)}
    csv.write_text("0,1,2,3,4\n1.5,1,2,3,4\n")
    with pytest.raises(SourceError, match=r"dets.csv: line 2: expected frame,x,y,w,h"):
        read_frame_boxes(csv, 2)
    js = tmp_path / "dets.json"
    det = {"scene_id": 1, "image_id": 4, "category_id": 2, "bbox": [1, 2, 3, 4], "score": 1}
    other = {**det, "category_id": 7, "image_id": 5}
    js.write_text(json.dumps([det, other]))
    assert read_frame_boxes(js, 2) == {4: (1.0, 2.0, 3.0, 4.0)}
    js.write_text(json.dumps([det, {**det, "scene_id": 2}]))
    with pytest.raises(SourceError, match="scenes"):
        read_frame_boxes(js, 2)


def test_init_box_parsing_and_placement():
    assert parse_box("10,20.5,30,40") == (10.0, 20.5, 30.0, 40.0)
    for bad in ("10,20,30", "a,b,c,d", "10,20,0,40", "1,2,3,nan"):
        with pytest.raises(Exception, match="expected x,y,w,h"):
            parse_box(bad)
    check_init_box((290.0, 200.0, 40.0, 60.0), 320, 240, "f.png")  # centre inside, box not
    with pytest.raises(SourceError, match=r"f.png: --init-box 400,10,20,20 lies outside"):
        check_init_box((400.0, 10.0, 20.0, 20.0), 320, 240, "f.png")
