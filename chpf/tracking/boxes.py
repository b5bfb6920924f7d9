"""Where the per-frame 2D detection boxes come from when tracking a BOP dataset.

1. ``--detections FILE``: a BOP detections JSON list ({"scene_id", "image_id", "category_id",
   "bbox": [x, y, w, h] px, "score", "time"}; the best-scoring box per image and object).
2. Without a file: the simulated detector (``chpf.detections.SimulatedDetector``: the visible
   ground-truth box of scene_gt_info.json with noise and missed frames; NOT a real detector).
   If the dataset root holds ``detections_sim.json`` (written by ``chpf-gen-data sequences``)
   its boxes are used; otherwise the detector runs on the fly on scene_gt_info.json.

``BoxChecker`` checks every box a tracker is given (the API's and the box sources'): text or
other non-numbers are an InputError; an invalid box (zero or negative size, non-finite, not 4
numbers) makes the frame predict-only, with one InvalidBoxWarning per run naming the frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from chpf.bop import (
    DETECTIONS_SIM,
    SCENE_GT_INFO,
    BopDataset,
    BopScene,
    read_detections,
    scene_dir,
)
from chpf.detections import SIMULATED_DETECTOR_DEFAULTS, SimulatedDetector
from chpf.errors import DatasetError, InputError
from chpf.tracking.candidates import valid_box
from chpf.tracking.types import Box
from chpf.tracking.warn import InvalidBoxWarning, OnceWarner


class BoxChecker(OnceWarner):
    """Checks the boxes of one run (see the module docstring); ``origin`` names where they come
    from in the warning (a detections file, "Tracker.step")."""

    def __init__(self, origin: str) -> None:
        super().__init__(InvalidBoxWarning)
        self.origin = origin

    def check(self, box: Any, frame: str) -> Box | None:
        """The box as 4 floats, or None (no box, or an invalid one: warned once per run)."""
        if box is None:
            return None
        if isinstance(box, (str, bytes)):
            raise InputError(f"box must be 4 numbers (x, y, w, h) in pixels, got text {box!r}")
        try:
            values = np.asarray(box, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise InputError(
                f"box must be 4 numbers (x, y, w, h) in pixels, got {type(box).__name__} {box!r}"
            ) from None
        checked = valid_box(box)
        if checked is None:
            shown = ", ".join(f"{v:g}" for v in values)
            self.warn(
                f"{self.origin}: {frame}: invalid box ({shown}) (needs 4 finite numbers x, y, w, "
                "h with w, h > 0); tracked without a box"
            )
        return checked


class BoxSource:
    """Boxes per (scene_id, im_id, obj_id). ``description`` is printed as the run's first line;
    ``origin`` names the boxes' file (or detector) in warnings."""

    description = ""
    origin = "simulated detector"
    simulated = False

    def start_scene(self, scene: BopScene) -> None:
        """Called before a scene's first frame (resets per-scene state)."""

    def box(self, scene: BopScene, im_id: int, obj_id: int, width: int, height: int) -> Box | None:
        raise NotImplementedError


class FileBoxes(BoxSource):
    """Boxes read from a BOP detections JSON file."""

    def __init__(self, path: Path, simulated: bool = False) -> None:
        self.boxes = read_detections(path)
        self.origin = str(path)
        self.simulated = simulated
        what = (
            "simulated detector (noisy visible ground-truth boxes, not a real detector)"
            if simulated
            else "detections"
        )
        self.description = f"detections: {what} from {path} ({len(self.boxes)} boxes)"

    def box(self, scene: BopScene, im_id: int, obj_id: int, width: int, height: int) -> Box | None:
        return self.boxes.get((scene.scene_id, im_id, obj_id))


class SimulatedBoxes(BoxSource):
    """The simulated detector run on the fly on scene_gt_info.json (seeded per scene; each
    object has its own detector with the scene's seed, so an object's boxes are the same
    whether it is tracked alone or with others)."""

    simulated = True

    def __init__(self, seed: int) -> None:
        self.cfg = dict(SIMULATED_DETECTOR_DEFAULTS)
        self.seed = int(seed)
        self.scene_id: int | None = None
        self.detectors: dict[int, SimulatedDetector] = {}
        self.description = (
            "detections: simulated detector (noisy visible ground-truth boxes from "
            "scene_gt_info.json, not a real detector)"
        )

    def start_scene(self, scene: BopScene) -> None:
        self.scene_id = scene.scene_id
        self.detectors = {}

    def _detector(self, obj_id: int) -> SimulatedDetector:
        assert self.scene_id is not None, "start_scene() first"
        if obj_id not in self.detectors:
            seq = np.random.SeedSequence([self.seed, 4, self.scene_id])
            self.detectors[obj_id] = SimulatedDetector(self.cfg, np.random.default_rng(seq))
        return self.detectors[obj_id]

    def box(self, scene: BopScene, im_id: int, obj_id: int, width: int, height: int) -> Box | None:
        gts = scene.gt.get(im_id, [])
        infos = scene.gt_info.get(im_id, [])
        for gt, info in zip(gts, infos, strict=False):
            if gt.obj_id == obj_id:
                det = self._detector(obj_id).detect(
                    scene.scene_id, im_id, obj_id, info, width, height
                )
                return None if det is None else tuple(det["bbox"])  # type: ignore[return-value]
        return None


def make_box_source(
    dataset: BopDataset, split: str, detections: Path | None, seed: int = 0
) -> BoxSource:
    """The box source for a run (see the module docstring); DatasetError if there is none."""
    if detections is not None:
        return FileBoxes(Path(detections))
    sim = dataset.root / DETECTIONS_SIM
    if sim.is_file():
        return FileBoxes(sim, simulated=True)
    has_info = any(
        (scene_dir(dataset.root, split, s) / SCENE_GT_INFO).is_file()
        for s in dataset.scene_ids(split)
    )
    if not has_info:
        raise DatasetError(
            f"{dataset.root}: no --detections given and no scene_gt_info.json for the simulated "
            "detector"
        )
    return SimulatedBoxes(seed)
