"""Build the frame source of ``chpf-track --images DIR`` / ``--video FILE`` (a "plain" input:
frames, a camera file and at most a few boxes, no ground truth)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from chpf.sources.boxes import PlainBoxes, check_init_box, read_frame_boxes
from chpf.sources.camera import read_camera
from chpf.sources.images import ImageFolder
from chpf.sources.video import VideoFile
from chpf.tracking.types import Box


def open_plain(
    images: Path | None,
    video: Path | None,
    camera: Path,
    obj_id: int | Sequence[int],
    fps: float,
    init_box: Box | Sequence[Box] | None = None,
    detections: Path | None = None,
    depth: Path | None = None,
    depth_scale: float | None = None,
) -> ImageFolder | VideoFile:
    """The source of one of ``images`` / ``video`` with the intrinsics of ``camera`` and the
    boxes of ``init_box`` (first frame) or ``detections`` (a CSV or BOP JSON file; the rows for
    ``obj_id``). ``depth_scale`` (mm per depth unit) defaults to the camera file's, else 1.
    Several objects: ``obj_id`` a list of obj_ids and ``init_box`` None or a list of as many
    boxes (each object's, in order); the frames then carry each object's box by obj_id.
    Everything that can be checked before tracking is (SourceError / ImageSizeError naming the
    file: sizes, counts, the init box inside the first frame)."""
    cam = read_camera(camera)
    several = not isinstance(obj_id, int)
    ids = list(obj_id) if several else [obj_id]  # type: ignore[arg-type]
    inits: list[Box | None] = (
        [None] * len(ids) if init_box is None else (list(init_box) if several else [init_box])  # type: ignore[list-item]
    )
    assert len(inits) == len(ids), "one init box per object"
    per = {
        o: PlainBoxes(None if detections is None else read_frame_boxes(detections, o), b)
        for o, b in zip(ids, inits, strict=True)
    }
    boxes = per if several else per[ids[0]]
    source: ImageFolder | VideoFile
    if images is not None:
        scale = depth_scale if depth_scale is not None else (cam.depth_scale or 1.0)
        source = ImageFolder(images, cam, boxes, fps, depth=depth, depth_scale=scale)
    else:
        assert video is not None, "give images or video"
        source = VideoFile(video, cam, boxes, fps)
    for b in inits:
        if b is not None:
            check_init_box(b, source.width, source.height, source.first_name)
    return source
