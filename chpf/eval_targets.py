"""Subsets of frames to score: BOP ``test_targets_*.json`` or a keyframe list.

- BOP targets: a JSON list of ``{"scene_id", "im_id", "obj_id", "inst_count"}``: only those
  objects in those images are scored.
- Keyframe list (as the YCB-Video toolbox's ``keyframe.txt``): one ``scene_id/im_id`` per line
  (``0048/000001``; blank lines and ``#`` comments skipped): every object in those images.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from chpf.errors import DatasetError

__all__ = ["Targets", "read_targets"]


@dataclass(frozen=True)
class Targets:
    """Frames to score: (scene_id, im_id) -> obj_ids (None: every object in the image)."""

    frames: dict[tuple[int, int], frozenset[int] | None]

    def keeps(self, scene_id: int, im_id: int, obj_id: int) -> bool:
        """Whether the instance of ``obj_id`` in image (scene_id, im_id) is scored."""
        objs = self.frames.get((scene_id, im_id), frozenset())
        return objs is None or obj_id in objs

    @property
    def scene_ids(self) -> set[int]:
        return {s for s, _ in self.frames}


def _bop_targets(doc: object, path: Path) -> Targets:
    if not isinstance(doc, list):
        raise DatasetError(f"{path}: expected a JSON list of targets")
    frames: dict[tuple[int, int], set[int]] = {}
    for i, t in enumerate(doc):
        try:
            key = (int(t["scene_id"]), int(t["im_id"]))
            obj = int(t["obj_id"])
        except (TypeError, KeyError, ValueError):
            raise DatasetError(
                f"{path}: target {i} lacks an integer scene_id, im_id or obj_id"
            ) from None
        frames.setdefault(key, set()).add(obj)
    return Targets({k: frozenset(v) for k, v in frames.items()})


def _keyframes(text: str, path: Path) -> Targets:
    frames: dict[tuple[int, int], frozenset[int] | None] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        scene, sep, im = line.partition("/")
        try:
            if not sep:
                raise ValueError
            frames[(int(scene), int(im))] = None
        except ValueError:
            raise DatasetError(f"{path}: line {n}: expected scene_id/im_id, got {line!r}") from None
    return Targets(frames)


def read_targets(path: str | Path) -> Targets:
    """Targets of a BOP ``.json`` target file or a keyframe list; DatasetError (one line)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise DatasetError(f"{p}: cannot read targets ({err})") from None
    if p.suffix.lower() == ".json":
        try:
            doc = json.loads(text)
        except ValueError:
            raise DatasetError(f"{p}: not valid JSON") from None
        targets = _bop_targets(doc, p)
    else:
        targets = _keyframes(text, p)
    if not targets.frames:
        raise DatasetError(f"{p}: no targets")
    return targets
