"""Track one object through sequences of frames with several methods at once.

A sequence is a scene id and a frame source (``chpf.sources``: a BOP scene, an image folder, a
video). Each frame is read once and given to every method's Tracker. Per method, a BOP result
CSV (``{method}_{dataset}-{split}.csv``, t in mm, readable by chpf-eval) and a frame log
(``log_{method}.csv``) are appended and flushed frame by frame. A rerun resumes: sequences whose
frames are all logged are skipped; a partly done one is tracked again from its first frame
(each sequence's filter is seeded with (seed, scene_id), so the redone frames repeat the same
poses) and only the missing frames are written. Sinks (the overlay, the poses stream) see every
frame tracked; with sinks every sequence is tracked again, so that they cover the whole run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from tqdm import tqdm

from chpf.bop import BopDataset, ResultRow, ResultsAppender
from chpf.metrics import add, adds
from chpf.sources.bop_scene import BopSceneFrames
from chpf.sources.frame import FrameSource, SourceFrame
from chpf.tracking.boxes import BoxChecker, BoxSource
from chpf.tracking.runlog import FrameLog
from chpf.tracking.timing import add_ms
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import TrackResult
from chpf.tracking.warn import MissingDepthWarning, OnceWarner

DEFAULT_FPS = 30.0
"""Frame rate of sources that record none (BOP scenes, image folders), for the frame times."""


class FrameSink(Protocol):
    """Receives every tracked frame's result (an overlay, a poses stream)."""

    def write(
        self, scene_id: int, frame: SourceFrame, method: str, result: TrackResult, ms: float
    ) -> None: ...

    def close(self, completed: bool) -> None:
        """End of the run; ``completed`` is False when it stopped on an error."""
        ...


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


def bop_sequences(
    dataset: BopDataset,
    split: str,
    scene_ids: list[int],
    obj_id: int,
    boxes: BoxSource,
    want_depth: bool,
    fps: float = DEFAULT_FPS,
) -> list[tuple[int, FrameSource]]:
    """The (scene_id, frames) sequences of a BOP dataset's scenes for ``run_sequences``, boxes
    from ``boxes``; depth read when ``want_depth`` (a frame without its depth image is tracked
    with RGB only, warned once per run)."""
    no_depth = OnceWarner(MissingDepthWarning)
    return [
        (sid, BopSceneFrames(dataset.scene(split, sid), boxes, obj_id, want_depth, no_depth, fps))
        for sid in scene_ids
    ]


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
    """``run_sequences`` over the scenes of a BOP dataset (``bop_sequences``; depth read only
    for trackers with modality "rgbd")."""
    want_depth = any(t.modality == "rgbd" for t in trackers.values())
    sequences = bop_sequences(dataset, split, scene_ids, obj_id, boxes, want_depth)
    name = dataset.root.resolve().name
    return run_sequences(
        trackers, sequences, obj_id, out, name, split, boxes.origin, seed, points, progress
    )


def run_sequences(
    trackers: dict[str, Tracker],
    sequences: list[tuple[int, FrameSource]],
    obj_id: int,
    out: Path,
    name: str,
    split: str,
    box_origin: str,
    seed: int = 0,
    points: np.ndarray | None = None,
    progress: bool = True,
    sinks: list[FrameSink] | None = None,
) -> dict[str, MethodRun]:
    """Run every tracker over the (scene_id, frames) sequences (see module docstring); returns
    per-method outputs, named ``output_paths(out, method, name, split)``.

    ``points`` (M,3) metres: model points for the per-frame ADD / ADD-S in the logs of frames
    with ground truth (None: no errors logged). An invalid box is tracked as no box (warned
    once, naming ``box_origin``).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sinks = sinks or []
    runs = {m: MethodRun(m, *output_paths(out, m, name, split)) for m in trackers}
    appenders = {m: ResultsAppender(r.results) for m, r in runs.items()}
    logs = {m: FrameLog(r.log) for m, r in runs.items()}
    checker = BoxChecker(box_origin)
    completed = False
    try:
        ids = {sid: frames.frame_ids() for sid, frames in sequences}
        total = sum(len(v) for v in ids.values()) * len(trackers) or None
        with tqdm(total=total, desc="tracking", unit="frame", disable=not progress or None) as bar:
            for sid, frames in sequences:
                logged = {m: logs[m].done_keys() for m in trackers}
                keys = [(sid, i, obj_id) for i in ids[sid]]
                todo = [
                    m
                    for m in trackers
                    if sinks or not keys or any(k not in logged[m] for k in keys)
                ]
                bar.update(len(ids[sid]) * (len(trackers) - len(todo)))
                if not todo:
                    continue
                for m in todo:
                    trackers[m].reset(seed=(int(seed), int(sid)))
                for frame in frames:
                    box = checker.check(frame.box, frame.name)
                    key = (sid, frame.index, obj_id)
                    for m in todo:
                        t0 = time.perf_counter()
                        r = trackers[m].step(frame.rgb, depth=frame.depth, K=frame.K, box=box)
                        ms = (time.perf_counter() - t0) * 1000.0
                        bar.update(1)
                        for sink in sinks:
                            sink.write(sid, frame, m, r, ms)
                        if key in logged[m]:
                            continue
                        runs[m].frames += 1
                        runs[m].ms += ms
                        add_ms(runs[m].stage_ms, r.stage_ms)
                        e_add = e_adds = float("nan")
                        if r.ok and frame.gt is not None and points is not None:
                            e_add = add(points, r.R, r.t, *frame.gt)
                            e_adds = adds(points, r.R, r.t, *frame.gt)
                        if r.ok and key not in appenders[m].done_keys():
                            score = r.sum_L / trackers[m].config.filter.n_particles
                            appenders[m].append(
                                ResultRow(
                                    sid,
                                    frame.index,
                                    obj_id,
                                    float(np.clip(np.nan_to_num(score), 0.0, 1.0)),
                                    r.R,
                                    r.t,
                                    ms / 1000.0,
                                )
                            )
                        logs[m].append(key, box is not None, r, e_add, e_adds)
        completed = True
    finally:
        for a in appenders.values():
            a.close()
        for lg in logs.values():
            lg.close()
        for sink in sinks:
            sink.close(completed)
    return runs
