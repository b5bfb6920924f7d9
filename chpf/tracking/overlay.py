"""``--overlay``: every tracked frame with the estimate drawn on it, as a video or PNGs.

Each frame shows the object's outline at the estimate (the convex hull of the projected
``chpf.tracking.model_outline`` points, green), its axes (x red, y green, z blue, half the
diameter long), the search region of a frame without a detection (a thin yellow rectangle,
chpf.tracking.search_region) and a bar of the filter's doubt: alpha (the share reinvigorated)
for the methods that have one, else the effective sample size over N. A frame without an
estimate says so. A target ending in a video suffix is written with ``cv2.VideoWriter`` (mp4v)
under a temporary name and moved into place when the run ends; any other target is a folder of
``SCENE_FRAME.png`` files (``000001_000042.png``), each written atomically. With several
methods each gets its own: ``NAME_METHOD.mp4`` or ``FOLDER/METHOD/``. With several objects
every object is drawn on the same frame, each with its own bar labelled with its obj_id and
name ("none" after it: no estimate).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from chpf.bop import write_rgb
from chpf.errors import ConfigError, OutputError
from chpf.outdir import check_out_dir, check_out_file
from chpf.sources.frame import SourceFrame
from chpf.tracking.run_dataset import ObjectResult, method_tag
from chpf.tracking.types import TrackResult

VIDEO_EXTS = (".mp4", ".avi", ".mov", ".mkv")
OUTLINE = (40, 220, 40)
REGION = (240, 220, 40)
AXES = ((230, 40, 40), (40, 220, 40), (60, 100, 255))
FONT = cv2.FONT_HERSHEY_SIMPLEX


ESS_BAR = (90, 160, 255)


def check_overlay_target(path: Path) -> bool:
    """Refuse an overlay target that cannot be written (OutputError) or is neither a video name
    nor a folder (ConfigError); True for a video."""
    suffix = path.suffix.lower()
    if suffix in VIDEO_EXTS:
        check_out_file(path)
        return True
    if suffix and not path.is_dir():
        raise ConfigError(
            f"--overlay {path}: give a video ({', '.join(VIDEO_EXTS)}) or a folder for PNGs"
        )
    check_out_dir(path)
    return False


def doubt(result: TrackResult, n_particles: int) -> tuple[float, str, bool] | None:
    """(bar fill in [0, 1], label, is alpha): alpha when finite, else ESS / N; None when
    neither is (a predict-only frame)."""
    if np.isfinite(result.alpha):
        return float(np.clip(result.alpha, 0.0, 1.0)), f"alpha {result.alpha:.2f}", True
    if np.isfinite(result.ess):
        fill = float(np.clip(result.ess / n_particles, 0.0, 1.0))
        return fill, f"ESS {result.ess:.0f}/{n_particles}", False
    return None


def _panel(img: np.ndarray, x1: int, y1: int) -> None:
    """Darken the top-left corner up to (x1, y1) so that the text on it reads on any frame."""
    corner = img[:y1, :x1]
    corner[:] = (corner * 0.35).astype(np.uint8)


@dataclass
class DrawnObject:
    """One object on an overlay frame: pose R (3,3), t (3,) metres (None: no estimate), its
    object-frame ``points`` (M,3), ``axis_length`` metres, the ``label`` before its bar, the
    ``bar`` (``doubt``'s, or None) and the search ``region`` (x, y, w, h) pixels (None: none)."""

    R: np.ndarray | None
    t: np.ndarray | None
    points: np.ndarray
    axis_length: float
    label: str
    bar: tuple[float, str, bool] | None
    region: tuple[float, float, float, float] | None = None


def _draw_pose(img: np.ndarray, K: np.ndarray, obj: DrawnObject, line: int) -> None:
    R, t = obj.R, obj.t
    cam = obj.points @ np.asarray(R).T + np.asarray(t)
    front = cam[cam[:, 2] > 1e-6]
    if len(front) >= 3:
        uv = front[:, :2] / front[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.polylines(img, [hull], True, OUTLINE, line, cv2.LINE_AA)
    ends = np.vstack([t, t + obj.axis_length * np.asarray(R).T]) @ np.asarray(K).T
    if np.all(ends[:, 2] > 1e-6):
        px = np.round(ends[:, :2] / ends[:, 2:]).astype(np.int64)
        for i, colour in enumerate(AXES):
            cv2.line(img, tuple(px[0]), tuple(px[i + 1]), colour, line + 1, cv2.LINE_AA)


def draw_objects(
    rgb: np.ndarray, K: np.ndarray, objects: list[DrawnObject], title: str
) -> np.ndarray:
    """A copy of ``rgb`` (H,W,3) uint8 with every object's pose drawn (outline, axes) and, at
    the top left, the ``title`` and one bar per object (alpha from green (0) to red (1), ESS in
    blue) followed by its label and the bar's."""
    img = np.ascontiguousarray(rgb).copy()
    h, w = img.shape[:2]
    scale = max(0.35, w / 1400.0)
    line = max(1, round(w / 400))
    for obj in objects:
        if obj.region is not None:
            x, y, rw, rh = (round(v) for v in obj.region)
            cv2.rectangle(img, (x, y), (x + rw - 1, y + rh - 1), REGION, 1)
        if obj.R is not None and obj.t is not None:
            _draw_pose(img, K, obj, line)
    pad = max(4, round(h / 60))
    text_h = int(cv2.getTextSize("Ag", FONT, scale, 1)[0][1])
    bw, bh = max(40, w // 5), max(6, h // 40)
    labels = [
        " ".join(s for s in (o.label, "" if o.bar is None else o.bar[1]) if s) for o in objects
    ]
    label_w = max((int(cv2.getTextSize(s, FONT, scale, 1)[0][0]) for s in labels), default=0)
    title_w = int(cv2.getTextSize(title, FONT, scale, 1)[0][0])
    row = max(bh, text_h) + pad
    rows = sum(1 for o, s in zip(objects, labels, strict=True) if o.bar is not None or s)
    _panel(
        img,
        min(w, 2 * pad + max(title_w, bw + pad + label_w)),
        min(h, 2 * pad + text_h + rows * row),
    )
    cv2.putText(img, title, (pad, pad + text_h), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
    y0 = 2 * pad + text_h
    for obj, label in zip(objects, labels, strict=True):
        if obj.bar is None and not label:
            continue
        x0 = pad
        if obj.bar is not None:
            fill, _, is_alpha = obj.bar
            colour = (int(255 * fill), int(200 * (1.0 - fill)), 40) if is_alpha else ESS_BAR
            cv2.rectangle(img, (x0, y0), (x0 + round(bw * fill), y0 + bh), colour, -1)
            cv2.rectangle(img, (x0, y0), (x0 + bw, y0 + bh), (255, 255, 255), 1)
        cv2.putText(
            img, label, (x0 + bw + pad, y0 + bh), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA
        )
        y0 += row
    return img


def draw_overlay(
    rgb: np.ndarray,
    K: np.ndarray,
    R: np.ndarray | None,
    t: np.ndarray | None,
    points: np.ndarray,
    axis_length: float,
    title: str,
    bar: tuple[float, str, bool] | None,
) -> np.ndarray:
    """``draw_objects`` of one object: a copy of ``rgb`` with the pose (R, t metres; None: no
    estimate, said in the title) drawn from the object-frame ``points`` (M,3), the ``title``
    and the ``bar`` (``doubt``'s) at the top left."""
    if R is None or t is None:
        title += "  no estimate"
    return draw_objects(rgb, K, [DrawnObject(R, t, points, axis_length, "", bar)], title)


class OverlayWriter:
    """A FrameSink (chpf.tracking.run_dataset) writing the overlay of each method to its target
    (module docstring), every object on the same frame. ``points``: {obj_id: (M,3) metres}
    (one object: an (M,3) array for ``obj_id``) and ``axis_length``: {obj_id: metres} (or one
    for all); ``names`` label each object's bar when there are several; ``fps`` of the video."""

    def __init__(
        self,
        target: str | Path,
        methods: list[str],
        points: np.ndarray | dict[int, np.ndarray],
        axis_length: float | dict[int, float],
        fps: float,
        n_particles: dict[str, int],
        names: dict[int, str] | None = None,
    ) -> None:
        target = Path(target)
        self.video = check_overlay_target(target)
        one = len(methods) == 1
        self.targets = {
            m: target
            if one
            else (
                target.with_name(f"{target.stem}_{method_tag(m)}{target.suffix}")
                if self.video
                else target / method_tag(m)
            )
            for m in methods
        }
        for path in self.targets.values():
            check_overlay_target(path)
        self.points = points
        self.axis_length = axis_length
        self.names = names or {}
        self.fps = float(fps)
        self.n_particles = n_particles
        self.writers: dict[str, tuple[cv2.VideoWriter, Path, tuple[int, int]]] = {}
        self.frames = dict.fromkeys(methods, 0)

    def _of(self, table: np.ndarray | float | dict, obj_id: int):
        return table[obj_id] if isinstance(table, dict) else table

    def write(
        self, scene_id: int, frame: SourceFrame, method: str, results: list[ObjectResult]
    ) -> None:
        title = f"{method}  frame {frame.index}"
        several = len(results) > 1
        drawn = []
        for obj in results:
            r: TrackResult = obj.result
            ok = bool(r.ok and r.R is not None and r.t is not None)
            label = ""
            if several:
                name = self.names.get(obj.obj_id, "")
                label = f"obj {obj.obj_id}" + (f" {name}" if name else "") + ("" if ok else " none")
            elif not ok:
                title += "  no estimate"
            drawn.append(
                DrawnObject(
                    r.R if ok else None,
                    r.t if ok else None,
                    self._of(self.points, obj.obj_id),
                    float(self._of(self.axis_length, obj.obj_id)),
                    label,
                    doubt(r, self.n_particles[method]),
                    r.region,
                )
            )
        img = draw_objects(frame.rgb, frame.K, drawn, title)
        if self.video:
            self._video_frame(method, img)
        else:
            write_rgb(self.targets[method] / f"{scene_id:06d}_{frame.index:06d}.png", img)
        self.frames[method] += 1

    def _video_frame(self, method: str, img: np.ndarray) -> None:
        if method not in self.writers:
            target = self.targets[method]
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{target.stem}.partial{target.suffix}")
            size = (img.shape[1], img.shape[0])
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, size)
            if not writer.isOpened():
                raise OutputError(f"{target}: cannot write a video here (OpenCV mp4v)")
            self.writers[method] = (writer, tmp, size)
        writer, _, size = self.writers[method]
        if (img.shape[1], img.shape[0]) != size:  # a scene of another size: fit to the first
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))

    def close(self, completed: bool) -> None:
        """Release the videos; move them into place when the run completed, else remove them."""
        for method, (writer, tmp, _) in self.writers.items():
            writer.release()
            if completed:
                os.replace(tmp, self.targets[method])
            else:
                tmp.unlink(missing_ok=True)
        self.writers.clear()
