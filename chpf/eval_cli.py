"""``chpf-eval``: score a BOP results CSV against a BOP dataset's ground truth, as the bop_toolkit
and the YCB-Video toolbox score it.

Usage::

    chpf-eval --dataset DIR --results FILE.csv [--split test] [--scenes 48,49]
              [--points vertices|sample|FILE] [--targets FILE] [--json OUT.json]

What is scored (errors in metres, AUC = VOCap area up to 0.1 m, x100):

- Objects: every object that has at least one row in the results. An object with no rows at all is
  not scored (so scoring a single-object tracking run is meaningful).
- Targets: every ground-truth instance of those objects in every scene of the split (or only in
  ``--scenes``; or only the frames of ``--targets``, chpf.eval_targets). A target with no
  estimate counts as a failure (error = inf).
- Model points (chpf.model_points): the model's vertices (``models_eval/`` when present) by
  default, as the bop_toolkit; ``--points FILE`` for a point file such as YCB-Video's
  ``points.xyz``; ``--points sample`` for chpf's surface sample.
- Estimates: per (scene, image, object) the rows are taken in decreasing score; if the object
  appears k times in the image, the k best rows are matched greedily (best score first) to the
  still-unmatched instance with the lowest error, separately for each error kind (as the BOP
  toolkit matches per error type). With one instance this is simply the best-scoring row. Extra
  rows (more than the image has instances: duplicates, counted in ``duplicate_rows``, the first
  one described in ``duplicate_example``) and rows for images without that object
  (``ignored_rows``) are not scored.
- Result obj_ids without ground truth in the scored scenes (``unknown_obj_ids``) and objects
  with ground truth but no rows (``unscored_obj_ids``) are listed; the command warns about both,
  and refuses (exit 2) a results file that is empty or names no object with ground truth.
- Error kinds: ADD (plain, every object), ADD-S (symmetric metric, every object) and ADD(-S):
  ADD-S for an object with symmetries in ``models_info.json``, ADD otherwise (as papers report).
- Per kind: the AUC and the accuracy at 0.1 diameter (% of instances with error < 0.1 d).
- ``all`` pools the errors of all targets of all scored objects (instance-weighted, the
  YCB-Video convention); ``mean_of_objects`` is the mean of the per-object figures.

Report (``evaluate``)::

    {"dataset", "split", "scenes": [...], "points", "ignored_rows", "duplicate_rows",
     "duplicate_example", "unknown_obj_ids", "unscored_obj_ids",
     "objects": {"<obj_id>": {"symmetric", "n", "n_missing", "add_auc", "add_acc", "adds_auc",
                              "adds_acc", "add_s_auc", "add_s_acc"}},
     "all": {same keys but symmetric}, "mean_of_objects": {the AUC and acc keys}}

AUCs and accuracies are None (JSON null) for an object with no targets.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.bop import BopDataset
from chpf.console import run_main, scene_list
from chpf.errors import DatasetError, ResultsFormatError
from chpf.eval_targets import Targets, read_targets
from chpf.model_points import POINT_SOURCES, model_points
from chpf.outdir import check_out_file, lock_output_path
from chpf.results import ResultRow, read_results_csv

__all__ = [
    "InstanceErrors",
    "cli",
    "duplicates",
    "evaluate",
    "format_table",
    "instance_errors",
    "main",
    "object_errors",
]

CHUNK = 256  # pose pairs per metrics call (bounds memory: CHUNK x points x 3)


def _batched(fn, points: np.ndarray, Re, te, Rg, tg) -> np.ndarray:
    out = [
        np.asarray(
            fn(points, Re[i : i + CHUNK], te[i : i + CHUNK], Rg[i : i + CHUNK], tg[i : i + CHUNK])
        )
        for i in range(0, len(Re), CHUNK)
    ]
    return np.concatenate(out) if out else np.zeros(0)


def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def _greedy(err: np.ndarray) -> np.ndarray:
    """err (n_est, n_gt), estimates in decreasing score -> best error per gt (inf if unmatched)."""
    best = np.full(err.shape[1], np.inf)
    free = np.ones(err.shape[1], dtype=bool)
    for row in err:
        cand = np.where(free, row, np.inf)
        j = int(np.argmin(cand))
        if free[j]:
            best[j] = row[j]
            free[j] = False
    return best


def object_errors(
    points: np.ndarray,
    targets: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]],
    estimates: dict[tuple[int, int], list[ResultRow]],
) -> tuple[np.ndarray, np.ndarray, int]:
    """ADD and ADD-S errors (m) of one object's targets, plus the number of ignored rows.

    ``targets``: (scene, im) -> [(R_gt, t_gt), ...] instances; ``estimates``: (scene, im) -> rows.
    Returns (add (n,), adds (n,), ignored) in target order, inf where no estimate matched;
    ``ignored`` counts the rows of images without a target (duplicates: ``duplicates``).
    """
    from chpf.metrics import add_batch, adds_batch

    pair_e, pair_g, blocks = [], [], []
    for key, gts in targets.items():
        rows = sorted(estimates.get(key, []), key=lambda r: -r.score)[: len(gts)]
        blocks.append((len(pair_e), len(rows), len(gts)))
        for r in rows:
            for g in gts:
                pair_e.append(r)
                pair_g.append(g)
    ignored = sum(len(v) for k, v in estimates.items() if k not in targets)
    if pair_e:
        Re = np.stack([r.R for r in pair_e])
        te = np.stack([r.t for r in pair_e])
        Rg = np.stack([g[0] for g in pair_g])
        tg = np.stack([g[1] for g in pair_g])
        e_add = _batched(add_batch, points, Re, te, Rg, tg)
        e_adds = _batched(adds_batch, points, Re, te, Rg, tg)
    else:
        e_add = e_adds = np.zeros(0)
    add, adds = [], []
    for start, n_est, n_gt in blocks:
        sl = slice(start, start + n_est * n_gt)
        add.append(_greedy(e_add[sl].reshape(n_est, n_gt)))
        adds.append(_greedy(e_adds[sl].reshape(n_est, n_gt)))
    return _cat(add), _cat(adds), ignored


def duplicates(
    obj_id: int,
    targets: dict[tuple[int, int], list],
    estimates: dict[tuple[int, int], list[ResultRow]],
) -> tuple[int, dict[str, Any] | None]:
    """Rows beyond the number of instances of their (scene, image) (duplicates: the best-scoring
    rows are kept, the first of equal scores), and a description of the first such image."""
    n, example = 0, None
    for key in sorted(estimates):
        extra = len(estimates[key]) - len(targets.get(key, ()))
        if key in targets and extra > 0:
            n += extra
            if example is None:
                rows = estimates[key]
                example = {
                    "scene_id": key[0],
                    "im_id": key[1],
                    "obj_id": obj_id,
                    "rows": len(rows),
                    "instances": len(targets[key]),
                    "kept_score": max(r.score for r in rows),
                }
    return n, example


@dataclass
class InstanceErrors:
    """Errors of one object's scored instances, in target order (inf where no estimate).

    keys: (scene_id, im_id) per instance; add, adds, add_s (n,) metres, add_s being ADD-S for a
    symmetric object and ADD otherwise; diameter (m) and symmetric from models_info.json.
    """

    keys: list[tuple[int, int]]
    add: np.ndarray
    adds: np.ndarray
    diameter: float
    symmetric: bool

    @property
    def add_s(self) -> np.ndarray:
        return self.adds if self.symmetric else self.add


METRICS = ("add", "adds", "add_s")
"""Error kinds of a report: plain ADD, plain ADD-S and ADD(-S) (by the object's symmetry)."""
LABELS = {"add": "ADD", "adds": "ADD-S", "add_s": "ADD(-S)"}


def _summary(errs: list[InstanceErrors]) -> dict[str, Any]:
    """n, n_missing, then per metric the AUC (0-10 cm, pooled) and the accuracy at 0.1 d."""
    from chpf.metrics import accuracy, auc

    first = np.concatenate([e.add for e in errs]) if errs else np.zeros(0)
    n = len(first)
    out: dict[str, Any] = {"n": n, "n_missing": int(np.sum(~np.isfinite(first)))}
    thr = _cat([np.full(len(e.add), 0.1 * e.diameter) for e in errs])
    for m in METRICS:
        d = _cat([getattr(e, m) for e in errs])
        out[f"{m}_auc"] = float(auc(d)) if n else None
        out[f"{m}_acc"] = accuracy(d, thr) if n else None
    return out


def _mean_of_objects(objects: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Mean over the objects with targets of their AUCs and accuracies."""
    scored = [v for v in objects.values() if v["n"]]
    return {
        f"{m}_{k}": float(np.mean([v[f"{m}_{k}"] for v in scored])) if scored else None
        for m in METRICS
        for k in ("auc", "acc")
    }


@dataclass
class Scored:
    """What instance_errors found: per scored object its InstanceErrors, the scenes, and the
    rows and objects that were not scored (see the module docstring)."""

    errors: dict[int, InstanceErrors]
    scene_ids: list[int]
    ignored_rows: int
    duplicate_rows: int
    duplicate_example: dict[str, Any] | None
    unknown_obj_ids: list[int]
    unscored_obj_ids: list[int]


def instance_errors(
    dataset_root: str | Path,
    results_rows: Iterable[ResultRow],
    split: str = "test",
    scenes: Iterable[int] | None = None,
    points: str | Path = "vertices",
    targets: Targets | None = None,
) -> Scored:
    """Per scored object its InstanceErrors, and what was not scored (Scored).

    points: "vertices" | "sample" | a point file (chpf.model_points); targets: only these
    frames (chpf.eval_targets).
    """
    ds = BopDataset(dataset_root)
    rows = list(results_rows)
    objs = sorted({r.obj_id for r in rows})
    scene_ids = ds.scene_ids(split)
    if scenes is not None:
        wanted = {int(s) for s in scenes}
        missing = sorted(wanted - set(scene_ids))
        if missing:
            raise DatasetError(f"{ds.split_path(split)}: no scene(s) {missing}")
        scene_ids = [s for s in scene_ids if s in wanted]
    if targets is not None:
        scene_ids = [s for s in scene_ids if s in targets.scene_ids]
    if len(objs) > 1 and points not in POINT_SOURCES:
        raise DatasetError(f"{points}: one point file for {len(objs)} objects {objs}")

    gts: dict[int, dict[tuple[int, int], list]] = {o: defaultdict(list) for o in objs}
    gt_ids: set[int] = set()
    for sid in scene_ids:
        scene = ds.scene(split, sid)
        for im_id, poses in scene.gt.items():
            for p in poses:
                gt_ids.add(p.obj_id)
                keep = targets is None or targets.keeps(sid, im_id, p.obj_id)
                if p.obj_id in gts and keep:
                    gts[p.obj_id][(sid, im_id)].append((p.R, p.t))
    estimates: dict[int, dict[tuple[int, int], list[ResultRow]]] = {
        o: defaultdict(list) for o in objs
    }
    for r in rows:
        estimates[r.obj_id][(r.scene_id, r.im_id)].append(r)

    out: dict[int, InstanceErrors] = {}
    ignored, n_dup, example = 0, 0, None
    for obj_id in objs:
        dup, ex = duplicates(obj_id, gts[obj_id], estimates[obj_id])
        n_dup += dup
        example = example or ex
        if gts[obj_id]:
            infos = ds.models_info()
            if obj_id not in infos:
                raise DatasetError(f"{ds.models_info_path}: no entry for object {obj_id}")
            info = infos[obj_id]
            pts = model_points(ds, obj_id, points)
            add, adds, ign = object_errors(pts, gts[obj_id], estimates[obj_id])
            keys = [k for k, g in gts[obj_id].items() for _ in g]
            sym = bool(info.symmetries_discrete or info.symmetries_continuous)
            out[obj_id] = InstanceErrors(keys, add, adds, float(info.diameter), sym)
        else:  # no ground truth at all: listed in unknown_obj_ids
            ign = 0
            out[obj_id] = InstanceErrors([], np.zeros(0), np.zeros(0), float("nan"), False)
        ignored += ign
    return Scored(
        out,
        scene_ids,
        ignored,
        n_dup,
        example,
        sorted(set(objs) - gt_ids),
        sorted(gt_ids - set(objs)),
    )


def evaluate(
    dataset_root: str | Path,
    results_rows: Iterable[ResultRow],
    split: str = "test",
    scenes: Iterable[int] | None = None,
    points: str | Path = "vertices",
    targets: Targets | None = None,
) -> dict[str, Any]:
    """Score ``results_rows`` against the ground truth of ``split`` (see the module docstring)."""
    sc = instance_errors(dataset_root, results_rows, split, scenes, points, targets)
    objects = {}
    for obj_id, e in sc.errors.items():
        objects[str(obj_id)] = {"symmetric": e.symmetric, **_summary([e])}
    return {
        "dataset": str(dataset_root),
        "split": split,
        "scenes": sc.scene_ids,
        "points": str(points),
        "objects": objects,
        "all": _summary(list(sc.errors.values())),
        "mean_of_objects": _mean_of_objects(objects),
        "ignored_rows": sc.ignored_rows,
        "duplicate_rows": sc.duplicate_rows,
        "duplicate_example": sc.duplicate_example,
        "unknown_obj_ids": sc.unknown_obj_ids,
        "unscored_obj_ids": sc.unscored_obj_ids,
    }


def report_warnings(report: dict[str, Any], results: Path, split_path: Path) -> list[str]:
    """One line per thing that was not scored: duplicates (naming the first and the row kept),
    rows of images without the object, obj_ids without ground truth and the reverse."""
    lines = []
    ex = report["duplicate_example"]
    if ex is not None:
        lines.append(
            f"{results}: {report['duplicate_rows']} duplicate rows (more rows for an image and "
            f"object than it has instances; first: scene {ex['scene_id']} image {ex['im_id']} "
            f"obj_id {ex['obj_id']}, {ex['rows']} rows for {ex['instances']} instance(s)); per "
            f"image the best-scoring rows were kept (there: score {ex['kept_score']:g}, the first "
            "of equal scores), the others ignored"
        )
    if report["ignored_rows"]:
        lines.append(
            f"{results}: {report['ignored_rows']} rows are for images without their object "
            "(matched no ground-truth instance); ignored"
        )
    if report["unknown_obj_ids"]:
        lines.append(
            f"the ground truth of {split_path} lacks obj_ids {report['unknown_obj_ids']} of "
            f"{results}; their rows are not scored"
        )
    if report["unscored_obj_ids"]:
        lines.append(
            f"obj_ids {report['unscored_obj_ids']} have ground truth in {split_path} but no result "
            f"rows in {results}; not scored (only the objects the results name are)"
        )
    return lines


def format_auc(v: float | None) -> str:
    """An AUC for a table: two decimals, "-" for None (no targets)."""
    return "-" if v is None else f"{v:.2f}"


def format_table(report: dict[str, Any]) -> str:
    """Text table per object, then ``all (pooled)`` and ``mean of objects``: n, missing, the
    AUC of ADD, ADD-S and ADD(-S), and ADD(-S) accuracy at 0.1 d."""
    head = (
        f"{'obj_id':<16} {'n':>7} {'missing':>7} {'ADD AUC':>8} {'ADD-S AUC':>9} "
        f"{'ADD(-S) AUC':>11} {'ADD(-S)<0.1d %':>14}"
    )
    lines = [head]
    entries = [(k, v) for k, v in report["objects"].items()]
    entries += [("all (pooled)", report["all"]), ("mean of objects", report["mean_of_objects"])]
    for name, e in entries:
        if name == "all (pooled)":
            lines.append("-" * len(head))
        n = f"{e['n']:>7d} {e['n_missing']:>7d}" if "n" in e else f"{'':>7} {'':>7}"
        lines.append(
            f"{name:<16} {n} {format_auc(e['add_auc']):>8} {format_auc(e['adds_auc']):>9} "
            f"{format_auc(e['add_s_auc']):>11} {format_auc(e['add_s_acc']):>14}"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``chpf-eval``; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="chpf-eval",
        description="Score a BOP results CSV (ADD / ADD-S AUC, YCB-Video convention).",
    )
    parser.add_argument("--dataset", required=True, type=Path, help="BOP dataset root")
    parser.add_argument("--results", required=True, type=Path, help="BOP results CSV")
    parser.add_argument("--split", default="test", help="split folder (default: test)")
    parser.add_argument("--scenes", type=scene_list, default=None, help="e.g. 48,49 (default all)")
    parser.add_argument(
        "--points",
        default="vertices",
        help="model points: vertices (default: models_eval/ or models/), sample (surface "
        "sample), or a point file in metres such as YCB-Video's points.xyz",
    )
    parser.add_argument(
        "--targets",
        type=Path,
        default=None,
        help="score only these frames: BOP test_targets_*.json or a scene_id/im_id list",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the report as JSON")
    args = parser.parse_args(argv)

    if args.json is not None:
        check_out_file(args.json)  # before the work, not after it
    rows = read_results_csv(args.results)
    if not rows:
        raise ResultsFormatError(f"{args.results}: no result rows; nothing to score")
    targets = read_targets(args.targets) if args.targets is not None else None
    report = evaluate(
        args.dataset, rows, args.split, args.scenes, points=args.points, targets=targets
    )
    split_path = BopDataset(args.dataset).split_path(args.split)
    if not set(report["objects"]) - {str(i) for i in report["unknown_obj_ids"]}:
        raise DatasetError(
            f"{args.results}: none of its obj_ids {report['unknown_obj_ids']} has ground truth "
            f"in {split_path} (obj_ids {report['unscored_obj_ids']}); nothing to score"
        )
    for line in report_warnings(report, args.results, split_path):
        print(f"warning: {line}", file=sys.stderr)
    print(format_table(report))
    if args.json is not None:
        with lock_output_path(args.json, "chpf-eval"):
            atomic_write_text(args.json, json.dumps(report, indent=2) + "\n")
    return 0


cli = run_main(main)
