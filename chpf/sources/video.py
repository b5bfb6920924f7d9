"""A video file (anything ``cv2.VideoCapture`` opens) as a frame source, read frame by frame."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from chpf.errors import SourceError
from chpf.sources.boxes import PlainBoxes, frame_boxes
from chpf.sources.camera import Camera
from chpf.sources.frame import SourceFrame
from chpf.tracking.warn import OnceWarner, SkippedFrameWarning

MAX_BAD_RUN = 25
"""Failed reads in a row after which a video counts as ended (its announced count may lie)."""


def _open(path: Path) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise SourceError(f"{path}: cannot open the video (not a video, or a codec OpenCV lacks)")
    return cap


class VideoFile:
    """The frames of video ``path``; ids are positions from 0, time = position / fps (the
    video's own frame rate, else ``fps``).

    Checked when built (SourceError naming the file): a file that does not open or has no
    readable first frame, the camera's size. While reading, an unreadable frame is skipped and a
    video that ends before the frame count it announces stops there, each with a
    SkippedFrameWarning (unreadable frames: once per run).
    """

    def __init__(
        self,
        path: str | Path,
        camera: Camera,
        boxes: PlainBoxes | dict[int, PlainBoxes],
        fps: float,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise SourceError(f"{self.path}: video file not found")
        self.camera = camera
        self.boxes = boxes
        cap = _open(self.path)
        try:
            ok, first = cap.read()
            if not ok or first is None:
                raise SourceError(f"{self.path}: no readable frame in the video")
            self.height, self.width = first.shape[:2]
            self.count = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
            own = float(cap.get(cv2.CAP_PROP_FPS))
        finally:
            cap.release()
        self.fps = own if np.isfinite(own) and own > 0 else float(fps)
        camera.check_size(self.width, self.height, self.path)

    @property
    def first_name(self) -> str:
        return f"{self.path} frame 0"

    def frame_ids(self) -> list[int]:
        """0 .. the announced frame count - 1 (empty when the container does not say)."""
        return list(range(self.count))

    def __iter__(self) -> Iterator[SourceFrame]:
        skipped = OnceWarner(SkippedFrameWarning)
        cap = _open(self.path)
        pos, bad, first = 0, 0, True
        try:
            while True:
                ok, bgr = cap.read()
                if not ok or bgr is None or bgr.shape[:2] != (self.height, self.width):
                    bad += 1
                    pos += 1
                    if bad >= MAX_BAD_RUN or pos >= self.count:
                        break
                    continue
                if bad:
                    lost = f"frame {pos - 1}" if bad == 1 else f"frames {pos - bad}-{pos - 1}"
                    skipped.warn(f"{self.path}: {lost} unreadable; skipped, the run goes on")
                    bad = 0
                box, boxes = frame_boxes(self.boxes, pos, first)
                first = False
                rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                yield SourceFrame(
                    pos,
                    rgb,
                    None,
                    self.camera.K,
                    box,
                    pos / self.fps,
                    f"{self.path} frame {pos}",
                    None,
                    boxes,
                )
                pos += 1
        finally:
            cap.release()
        end = pos - bad
        if end < self.count:
            warnings.warn(
                f"{self.path}: the video ends at frame {end} of the {self.count} it announces; "
                "the run goes on with the frames read",
                SkippedFrameWarning,
                stacklevel=2,
            )
