"""Several objects in the same frames: a MultiTracker holds one Tracker per object.

Example::

    from chpf.tracking.multi import MultiTracker
    multi = MultiTracker.from_bundles(["bundles/mug", "bundles/can"], method="chpf")
    for rgb, K in frames:
        results = multi.step(rgb, K=K, boxes=[mug_box, None])  # one TrackResult per object
        mug, can = results

Each object's Tracker steps the same frame in turn (the frame is read once by the caller);
objects are named by their obj_id (each bundle's own, or ``obj_ids``), which must differ.
``boxes``: None (no box for any object: each tracker predicts or uses its estimate), a list
with one box (or None) per object in order, or a dict {obj_id: box}. Seeds: every object's
tracker gets the seed as it is, so each object's poses are those a lone Tracker with that seed
gives on the same frames and boxes: adding an object changes no other object's results (the
filters share nothing; two trackers of one bundle draw the same random numbers, which is
harmless as they track different objects).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from chpf.bundle import Bundle
from chpf.errors import ConfigError
from chpf.tracking.tracker import Tracker
from chpf.tracking.types import Box, TrackResult


class MultiTracker:
    """One Tracker per object over the same frames (module docstring).

    trackers: the objects' Trackers, in order; obj_ids: their obj_ids (default: each tracker's
    bundle's obj_id); ConfigError when two are equal or the counts differ. ``last_ms``: each
    object's milliseconds in the last ``step``.
    """

    def __init__(self, trackers: Sequence[Tracker], obj_ids: Sequence[int] | None = None) -> None:
        trackers = list(trackers)
        if not trackers:
            raise ConfigError("MultiTracker needs at least one Tracker")
        ids = (
            [int(t.bundle.obj_info.obj_id) for t in trackers]
            if obj_ids is None
            else [int(o) for o in obj_ids]
        )
        if len(ids) != len(trackers):
            raise ConfigError(f"MultiTracker: {len(trackers)} trackers but {len(ids)} obj_ids")
        dup = sorted({o for o in ids if ids.count(o) > 1})
        if dup:
            raise ConfigError(
                f"MultiTracker: obj_id(s) {dup} given to more than one object; give each object "
                "its own obj_id (obj_ids=, or chpf-track --obj-id once per --bundle)"
            )
        self.trackers = trackers
        self.obj_ids = ids
        self.last_ms = [0.0] * len(trackers)
        self.seed: int | Sequence[int] = trackers[0].seed
        self.reset()

    @classmethod
    def from_bundles(
        cls,
        paths: Sequence[str | Path | Bundle],
        method: str = "chpf",
        obj_ids: Sequence[int] | None = None,
        **kwargs: Any,
    ) -> MultiTracker:
        """A MultiTracker of ``Tracker.from_bundle(path, method, **kwargs)`` per path (the same
        method, config and seed for all; a path given twice loads its bundle once)."""
        loaded: dict[str, Tracker] = {}
        trackers = []
        for p in paths:
            key = str(Path(p.path if isinstance(p, Bundle) else p).resolve())
            src = loaded[key].bundle if key in loaded else p
            t = Tracker.from_bundle(src, method=method, **kwargs)
            loaded.setdefault(key, t)
            trackers.append(t)
        return cls(trackers, obj_ids)

    def __len__(self) -> int:
        return len(self.trackers)

    @property
    def method(self) -> str:
        return self.trackers[0].method

    @property
    def modality(self) -> str:
        return self.trackers[0].modality

    @property
    def config(self) -> Any:
        return self.trackers[0].config

    def reset(self, seed: int | Sequence[int] | None = None) -> None:
        """Start a new sequence for every object (optionally with a new seed; seeds: module
        docstring)."""
        if seed is not None:
            self.seed = seed
        for t in self.trackers:
            t.reset(self.seed)

    def _boxes(self, boxes: Sequence[Box | None] | Mapping[int, Box | None] | None) -> list:
        if boxes is None:
            return [None] * len(self.trackers)
        if isinstance(boxes, Mapping):
            unknown = sorted(set(boxes) - set(self.obj_ids))
            if unknown:
                raise ConfigError(
                    f"MultiTracker.step: boxes for obj_id(s) {unknown}; tracked: {self.obj_ids}"
                )
            return [boxes.get(o) for o in self.obj_ids]
        boxes = list(boxes)
        if len(boxes) != len(self.trackers):
            raise ConfigError(
                f"MultiTracker.step: {len(boxes)} boxes for {len(self.trackers)} objects "
                "(give one box or None per object, in order, or a dict by obj_id)"
            )
        return boxes

    def step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        K: np.ndarray | None = None,
        boxes: Sequence[Box | None] | Mapping[int, Box | None] | None = None,
    ) -> list[TrackResult]:
        """One frame for every object (see ``Tracker.step``); returns one TrackResult per
        object, in order."""
        per = self._boxes(boxes)
        results = []
        for k, (t, box) in enumerate(zip(self.trackers, per, strict=True)):
            t0 = time.perf_counter()
            results.append(t.step(rgb, depth=depth, K=K, box=box))
            self.last_ms[k] = (time.perf_counter() - t0) * 1000.0
        return results
