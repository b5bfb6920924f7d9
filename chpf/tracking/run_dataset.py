"""Track one object, or several, through sequences of frames with several methods at once.

A sequence is a scene id and a frame source (``chpf.sources``: a BOP scene, an image folder, a
video). Each frame is read once and given to every method's Tracker (one object) or
MultiTracker (several objects, ``chpf.tracking.multi``: each object's box is the frame's
``box_of(obj_id)``). Per method, a BOP result CSV (``{method}_{dataset}-{split}.csv``, t in mm,
readable by chpf-eval; with several objects it holds the rows of all, told apart by obj_id) and
per object a frame log (``log_{method}.csv``; with several objects
``log_{method}_obj{obj_id}.csv``) are appended and flushed frame by frame. A rerun resumes:
sequences whose frames are all logged are skipped; a partly done one is tracked again from its
first frame (each sequence's filter is seeded with (seed, scene_id), so the redone frames
repeat the same poses) and only the missing frames are written. Sinks (the overlay, the poses
stream) see every frame tracked; with sinks every sequence is tracked again, so that they cover
the whole run.
"""

from __future__ import annotations

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
from chpf.tracking.multi import MultiTracker
from chpf.tracking.runlog import FrameLog
from chpf.tracking.timing import add_ms
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import TrackResult
from chpf.tracking.warn import MissingDepthWarning, OnceWarner

DEFAULT_FPS = 30.0
"""Frame rate of sources that record none (BOP scenes, image folders), for the frame times."""


@dataclass
class ObjectResult:
    """One object's result of a frame for the sinks: its obj_id, the TrackResult, the
    milliseconds it took and whether the frame gave it a box."""

    obj_id: int
    result: TrackResult
    ms: float
    has_box: bool


class FrameSink(Protocol):
    """Receives every tracked frame's results, all objects of a method at once (an overlay, a
    poses stream)."""

    def write(
        self, scene_id: int, frame: SourceFrame, method: str, results: list[ObjectResult]
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


def output_paths(
    out: Path, method: str, dataset_name: str, split: str, obj_id: int | None = None
) -> tuple[Path, Path]:
    """(result CSV, frame log) of a method's run in folder ``out``; ``obj_id`` (runs of
    several objects): the object's log, ``log_METHOD_objN.csv`` (the CSV is shared)."""
    log = f"log_{method_tag(method)}" + ("" if obj_id is None else f"_obj{int(obj_id)}")
    return out / result_name(method, dataset_name, split), out / f"{log}.csv"


def run_label(method: str, obj_id: int, several: bool) -> str:
    """The key of a (method, object) run in ``run_sequences``' result: the method alone for
    one object, else ``"METHOD obj N"``."""
    return f"{method} obj {obj_id}" if several else method


@dataclass
class MethodRun:
    """Where a method's outputs for one object went and how long its new frames took."""

    method: str
    results: Path
    log: Path
    obj_id: int | None = None
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
    obj_id: int | list[int],
    boxes: BoxSource,
    want_depth: bool,
    fps: float = DEFAULT_FPS,
) -> list[tuple[int, FrameSource]]:
    """The (scene_id, frames) sequences of a BOP dataset's scenes for ``run_sequences``, boxes
    of object ``obj_id`` (a list: of each object) from ``boxes``; depth read when
    ``want_depth`` (a frame without its depth image is tracked with RGB only, warned once per
    run)."""
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
    trackers: dict[str, Tracker] | dict[str, MultiTracker],
    sequences: list[tuple[int, FrameSource]],
    obj_id: int | None,
    out: Path,
    name: str,
    split: str,
    box_origin: str,
    seed: int = 0,
    points: np.ndarray | dict[int, np.ndarray] | None = None,
    progress: bool = True,
    sinks: list[FrameSink] | None = None,
) -> dict[str, MethodRun]:
    """Run every method's tracker over the (scene_id, frames) sequences (see module docstring);
    returns the outputs per method and object, keyed ``run_label(method, obj_id, several)``
    and named ``output_paths``.

    ``trackers``: per method a Tracker of the object ``obj_id``, or a MultiTracker (its
    obj_ids; ``obj_id`` is then unused; all methods' must track the same objects).
    ``points`` (M,3) metres, or {obj_id: (M,3)} for several objects: model points for the
    per-frame ADD / ADD-S in the logs of frames with ground truth (None: no errors logged).
    An invalid box is tracked as no box (warned once, naming ``box_origin``).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sinks = sinks or []
    multi: dict[str, MultiTracker] = {}
    for m, t in trackers.items():
        if isinstance(t, MultiTracker):
            multi[m] = t
        else:
            assert obj_id is not None, "a Tracker needs the obj_id it tracks"
            multi[m] = MultiTracker([t], [obj_id])
    obj_ids = next(iter(multi.values())).obj_ids if multi else []
    assert all(t.obj_ids == obj_ids for t in multi.values()), "the same objects for all methods"
    several = len(obj_ids) > 1
    if isinstance(points, dict):
        obj_points = {o: points.get(o) for o in obj_ids}
    else:
        obj_points = dict.fromkeys(obj_ids, points)
    runs = {
        (m, o): MethodRun(m, *output_paths(out, m, name, split, o if several else None), o)
        for m in multi
        for o in obj_ids
    }
    appenders = {m: ResultsAppender(runs[m, obj_ids[0]].results) for m in multi}
    logs = {mo: FrameLog(r.log) for mo, r in runs.items()}
    checker = BoxChecker(box_origin)
    completed = False
    try:
        ids = {sid: frames.frame_ids() for sid, frames in sequences}
        total = sum(len(v) for v in ids.values()) * len(multi) or None
        with tqdm(total=total, desc="tracking", unit="frame", disable=not progress or None) as bar:
            for sid, frames in sequences:
                logged = {mo: logs[mo].done_keys() for mo in runs}
                todo = [
                    m
                    for m in multi
                    if sinks
                    or not ids[sid]
                    or any((sid, i, o) not in logged[m, o] for o in obj_ids for i in ids[sid])
                ]
                bar.update(len(ids[sid]) * (len(multi) - len(todo)))
                if not todo:
                    continue
                for m in todo:
                    multi[m].reset(seed=(int(seed), int(sid)))
                for frame in frames:
                    boxes = [checker.check(frame.box_of(o), frame.name) for o in obj_ids]
                    for m in todo:
                        results = multi[m].step(
                            frame.rgb, depth=frame.depth, K=frame.K, boxes=boxes
                        )
                        bar.update(1)
                        done = [
                            ObjectResult(o, r, ms, b is not None)
                            for o, r, ms, b in zip(
                                obj_ids, results, multi[m].last_ms, boxes, strict=True
                            )
                        ]
                        for sink in sinks:
                            sink.write(sid, frame, m, done)
                        n = multi[m].config.filter.n_particles
                        for d in done:
                            _record(
                                runs[m, d.obj_id],
                                appenders[m],
                                logs[m, d.obj_id],
                                logged[m, d.obj_id],
                                (sid, frame.index, d.obj_id),
                                d,
                                frame.gt_of(d.obj_id),
                                obj_points[d.obj_id],
                                n,
                            )
        completed = True
    finally:
        for a in appenders.values():
            a.close()
        for lg in logs.values():
            lg.close()
        for sink in sinks:
            sink.close(completed)
    return {run_label(m, o, several): r for (m, o), r in runs.items()}


def _record(
    run: MethodRun,
    appender: ResultsAppender,
    log: FrameLog,
    logged: set,
    key: tuple[int, int, int],
    done: ObjectResult,
    gt: tuple[np.ndarray, np.ndarray] | None,
    points: np.ndarray | None,
    n_particles: int,
) -> None:
    """Append one object's frame to its result CSV and log (unless logged before)."""
    if key in logged:
        return
    r, ms = done.result, done.ms
    run.frames += 1
    run.ms += ms
    add_ms(run.stage_ms, r.stage_ms)
    e_add = e_adds = float("nan")
    if r.ok and gt is not None and points is not None:
        e_add = add(points, r.R, r.t, *gt)
        e_adds = adds(points, r.R, r.t, *gt)
    if r.ok and key not in appender.done_keys():
        score = r.sum_L / n_particles
        appender.append(
            ResultRow(
                key[0],
                key[1],
                key[2],
                float(np.clip(np.nan_to_num(score), 0.0, 1.0)),
                r.R,
                r.t,
                ms / 1000.0,
            )
        )
    log.append(key, done.has_box, r, e_add, e_adds)
