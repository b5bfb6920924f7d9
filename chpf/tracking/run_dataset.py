"""Track one object through the scenes of a BOP dataset with several methods at once.

Each frame is read once and given to every method's Tracker. Per method, a BOP result CSV
(``{method}_{dataset}-{split}.csv``, t in mm, readable by chpf-eval) and a frame log
(``log_{method}.csv``) are appended and flushed frame by frame. A rerun resumes: scenes whose
frames are all logged are skipped; a partly done scene is tracked again from its first frame
(each scene's filter is seeded with (seed, scene_id), so the redone frames repeat the same
poses) and only the missing frames are written.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from chpf.bop import BopDataset, BopScene, ResultRow, ResultsAppender
from chpf.metrics import add, adds
from chpf.tracking.boxes import BoxChecker, BoxSource
from chpf.tracking.runlog import FrameLog
from chpf.tracking.timing import add_ms
from chpf.tracking.tracker import Tracker
from chpf.tracking.warn import MissingDepthWarning, OnceWarner


def method_tag(method: str) -> str:
    """File-name form of a method (BOP result names allow no '+' or '_')."""
    return method.replace("++", "pp").replace("_", "-")


def result_name(method: str, dataset_name: str, split: str) -> str:
    """BOP result file name ``METHOD_DATASET-SPLIT.csv``."""
    return f"{method_tag(method)}_{dataset_name.replace('_', '-')}-{split}.csv"


def output_paths(out: Path, method: str, dataset_name: str, split: str) -> tuple[Path, Path]:
    """(result CSV, frame log) of a method's run in folder ``out``."""
    return out / result_name(method, dataset_name, split), out / f"log_{method_tag(method)}.csv"


@dataclass
class MethodRun:
    """Where a method's outputs went and how long its new frames took."""

    method: str
    results: Path
    log: Path
    frames: int = 0
    ms: float = 0.0
    stage_ms: dict[str, float] = field(default_factory=dict)

    @property
    def fps(self) -> float:
        return 1000.0 * self.frames / self.ms if self.ms > 0 else float("nan")


def _gt_pose(scene: BopScene, im_id: int, obj_id: int):
    for p in scene.gt.get(im_id, []):
        if p.obj_id == obj_id:
            return p
    return None


def run_dataset(
    trackers: dict[str, Tracker],
    dataset: BopDataset,
    split: str,
    scene_ids: list[int],
    obj_id: int,
    boxes: BoxSource,
    out: Path,
    seed: int = 0,
    points: np.ndarray | None = None,
    progress: bool = True,
) -> dict[str, MethodRun]:
    """Run every tracker over the scenes (see module docstring); returns per-method outputs.

    ``points`` (M,3) metres: model points for the per-frame ADD / ADD-S in the logs (None: no
    errors logged). Depth is read only for trackers with modality "rgbd"; a frame without its
    depth image is tracked with RGB only, and an invalid box as no box (each warned once).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    name = dataset.root.resolve().name
    runs = {m: MethodRun(m, *output_paths(out, m, name, split)) for m in trackers}
    appenders = {m: ResultsAppender(r.results) for m, r in runs.items()}
    logs = {m: FrameLog(r.log) for m, r in runs.items()}
    want_depth = any(t.modality == "rgbd" for t in trackers.values())
    checker = BoxChecker(boxes.origin)
    no_depth = OnceWarner(MissingDepthWarning)
    try:
        scenes = [(sid, dataset.scene(split, sid)) for sid in scene_ids]
        total = sum(len(s.image_ids()) for _, s in scenes) * len(trackers)
        with tqdm(total=total, desc="tracking", unit="frame", disable=not progress or None) as bar:
            for sid, scene in scenes:
                ims = scene.image_ids()
                logged = {m: logs[m].done_keys() for m in trackers}
                todo = [m for m in trackers if any((sid, i, obj_id) not in logged[m] for i in ims)]
                bar.update(len(ims) * (len(trackers) - len(todo)))
                if not todo:
                    continue
                boxes.start_scene(scene)
                for m in todo:
                    trackers[m].reset(seed=(int(seed), int(sid)))
                for im in ims:
                    rgb = scene.rgb(im)
                    depth = scene.depth(im) if want_depth else None
                    if want_depth and depth is None:
                        no_depth.warn(
                            f"{scene.depth_path(im)}: no depth image for scene {sid} image {im} "
                            "of an RGB-D run; tracked with RGB only"
                        )
                    K = scene.camera(im).K
                    box = checker.check(
                        boxes.box(scene, im, obj_id, rgb.shape[1], rgb.shape[0]),
                        f"scene {sid} image {im}",
                    )
                    gt = _gt_pose(scene, im, obj_id)
                    key = (sid, im, obj_id)
                    for m in todo:
                        t0 = time.perf_counter()
                        r = trackers[m].step(rgb, depth=depth, K=K, box=box)
                        ms = (time.perf_counter() - t0) * 1000.0
                        bar.update(1)
                        if key in logged[m]:
                            continue
                        runs[m].frames += 1
                        runs[m].ms += ms
                        add_ms(runs[m].stage_ms, r.stage_ms)
                        e_add = e_adds = float("nan")
                        if r.ok and gt is not None and points is not None:
                            e_add = add(points, r.R, r.t, gt.R, gt.t)
                            e_adds = adds(points, r.R, r.t, gt.R, gt.t)
                        if r.ok and key not in appenders[m].done_keys():
                            score = r.sum_L / trackers[m].config.filter.n_particles
                            appenders[m].append(
                                ResultRow(
                                    sid,
                                    im,
                                    obj_id,
                                    float(np.clip(np.nan_to_num(score), 0.0, 1.0)),
                                    r.R,
                                    r.t,
                                    ms / 1000.0,
                                )
                            )
                        logs[m].append(key, box is not None, r, e_add, e_adds)
    finally:
        for a in appenders.values():
            a.close()
        for lg in logs.values():
            lg.close()
    return runs
