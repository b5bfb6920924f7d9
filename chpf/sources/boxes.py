"""Boxes of a plain input (image folder or video): ``--init-box`` or a detections file.

``--init-box x,y,w,h`` gives the first frame's box only; ``--detections FILE`` gives boxes by
frame id, from a CSV ``frame,x,y,w,h[,score]`` (``.csv``) or a BOP detections JSON (matched by
``image_id`` and the bundle's obj_id as ``category_id``; one scene only). Frames without a box
go to the tracker with ``box=None``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from chpf.detections import read_detections, read_detections_csv
from chpf.errors import SourceError
from chpf.tracking.types import Box


def parse_box(text: str) -> Box:
    """argparse type of ``--init-box``: "x,y,w,h" pixels, finite, w and h > 0."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4 or not all(map(math.isfinite, values)) or min(values[2:]) <= 0:
        raise argparse.ArgumentTypeError(
            f"expected x,y,w,h in pixels (4 numbers, w and h > 0), got {text!r}"
        )
    return (values[0], values[1], values[2], values[3])


def check_init_box(box: Box, width: int, height: int, frame: str) -> None:
    """SourceError naming ``frame`` when the box's centre lies outside its width x height image."""
    cx, cy = box[0] + box[2] / 2.0, box[1] + box[3] / 2.0
    if not (0.0 <= cx < width and 0.0 <= cy < height):
        shown = ",".join(f"{v:g}" for v in box)
        raise SourceError(
            f"{frame}: --init-box {shown} lies outside the {width}x{height} image (its centre "
            f"{cx:g},{cy:g} must be inside)"
        )


def read_frame_boxes(path: str | Path, obj_id: int) -> dict[int, Box]:
    """``{frame id: box}`` of a CSV or BOP JSON detections file (module docstring)."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_detections_csv(path)
    dets = read_detections(path)
    scenes = sorted({s for s, _, _ in dets})
    if len(scenes) > 1:
        raise SourceError(
            f"{path}: holds detections of scenes {scenes}; an image folder or video is one scene"
        )
    return {im: box for (_, im, obj), box in dets.items() if obj == obj_id}


class PlainBoxes:
    """The box of each frame of a plain input: ``init`` on the first frame read, else the
    detections' box of the frame id (``by_frame``), else None."""

    def __init__(self, by_frame: dict[int, Box] | None = None, init: Box | None = None) -> None:
        self.by_frame = by_frame or {}
        self.init = init

    def box(self, index: int, first: bool) -> Box | None:
        """The box of frame ``index``; ``first``: it is the first frame read."""
        if self.init is not None:
            return self.init if first else None
        return self.by_frame.get(index)


def frame_boxes(
    boxes: PlainBoxes | dict[int, PlainBoxes], index: int, first: bool
) -> tuple[Box | None, dict[int, Box | None] | None]:
    """(box, boxes by obj_id) of frame ``index`` for ``SourceFrame``: one object's PlainBoxes
    give (its box, None); several objects' ({obj_id: PlainBoxes}) give (the first's, all)."""
    if isinstance(boxes, PlainBoxes):
        return boxes.box(index, first), None
    per = {o: b.box(index, first) for o, b in boxes.items()}
    return next(iter(per.values()), None), per
