"""The frame-source protocol shared by BOP scenes, image folders and videos."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from chpf.tracking.types import Box


@dataclass
class SourceFrame:
    """One frame as a source yields it.

    index: the frame's id (the BOP im_id; an image folder's numeric file name or position; a
    video's frame position from 0). rgb (H,W,3) uint8; depth (H,W) float32 metres (0 = missing)
    or None; K (3,3); box (x, y, w, h) pixels or None (the tracker gets box=None); time: seconds
    from the source's start; name: the frame in messages (its file, or "VIDEO frame 7");
    gt: the ground-truth pose (R (3,3), t (3,) metres) when the source has one.
    With several objects (``boxes`` / ``gts`` not None) those hold each object's box and
    ground truth by obj_id, and ``box`` / ``gt`` are the first object's; read them with
    ``box_of`` / ``gt_of``.
    """

    index: int
    rgb: np.ndarray
    depth: np.ndarray | None
    K: np.ndarray
    box: Box | None
    time: float
    name: str
    gt: tuple[np.ndarray, np.ndarray] | None = None
    boxes: dict[int, Box | None] | None = None
    gts: dict[int, tuple[np.ndarray, np.ndarray] | None] | None = None

    def box_of(self, obj_id: int) -> Box | None:
        """The box of object ``obj_id`` (the frame's only box when it has one object)."""
        return self.box if self.boxes is None else self.boxes.get(obj_id)

    def gt_of(self, obj_id: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The ground truth of object ``obj_id`` (the frame's only one with one object)."""
        return self.gt if self.gts is None else self.gts.get(obj_id)


class FrameSource(Protocol):
    """A sequence of frames read one at a time. ``path`` names it in messages; ``fps`` is its
    frame rate (a video's own, else the one given)."""

    path: Path
    fps: float

    def frame_ids(self) -> list[int]:
        """The ids it announces, in order (a video may deliver fewer)."""
        ...

    def __iter__(self) -> Iterator[SourceFrame]: ...
