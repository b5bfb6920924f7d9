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
  rows and rows for images without that object are ignored (counted in ``ignored_rows``).
- Error kinds: ADD (plain, every object), ADD-S (symmetric metric, every object) and ADD(-S):
  ADD-S for an object with symmetries in ``models_info.json``, ADD otherwise (as papers report).
- Per kind: the AUC and the accuracy at 0.1 diameter (% of instances with error < 0.1 d).
- ``all`` pools the errors of all targets of all scored objects (instance-weighted, the
  YCB-Video convention); ``mean_of_objects`` is the mean of the per-object figures.

Report (``evaluate``)::

    {"dataset", "split", "scenes": [...], "points", "ignored_rows",
     "objects": {"<obj_id>": {"symmetric", "n", "n_missing", "add_auc", "add_acc", "adds_auc",
                              "adds_acc", "add_s_auc", "add_s_acc"}},
     "all": {same keys but symmetric}, "mean_of_objects": {the AUC and acc keys}}

AUCs and accuracies are None (JSON null) for an object with no targets.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.bop import BopDataset
from chpf.console import run_main, scene_list
from chpf.errors import DatasetError
from chpf.eval_targets import Targets, read_targets
from chpf.model_points import POINT_SOURCES, model_points
from chpf.outdir import lock_output_path
from chpf.results import ResultRow, read_results_csv

__all__ = [
    "InstanceErrors",
    "cli",
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
    Returns (add (n,), adds (n,), ignored) in target order, inf where no estimate matched.
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
    ignored += sum(max(0, len(estimates.get(k, [])) - len(g)) for k, g in targets.items())
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


def instance_errors(
    dataset_root: str | Path,
    results_rows: Iterable[ResultRow],
    split: str = "test",
    scenes: Iterable[int] | None = None,
    points: str | Path = "vertices",
    targets: Targets | None = None,
) -> tuple[dict[int, InstanceErrors], list[int], int]:
    """Per scored object its InstanceErrors; also the scene ids and the ignored row count.

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
    for sid in scene_ids:
        scene = ds.scene(split, sid)
        for im_id, poses in scene.gt.items():
            for p in poses:
                keep = targets is None or targets.keeps(sid, im_id, p.obj_id)
                if p.obj_id in gts and keep:
                    gts[p.obj_id][(sid, im_id)].append((p.R, p.t))
    estimates: dict[int, dict[tuple[int, int], list[ResultRow]]] = {
        o: defaultdict(list) for o in objs
    }
    for r in rows:
        estimates[r.obj_id][(r.scene_id, r.im_id)].append(r)

    out: dict[int, InstanceErrors] = {}
    ignored = 0
    for obj_id in objs:
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
        else:
            ign = sum(len(v) for v in estimates[obj_id].values())
            out[obj_id] = InstanceErrors([], np.zeros(0), np.zeros(0), float("nan"), False)
        ignored += ign
    return out, scene_ids, ignored


def evaluate(
    dataset_root: str | Path,
    results_rows: Iterable[ResultRow],
    split: str = "test",
    scenes: Iterable[int] | None = None,
    points: str | Path = "vertices",
    targets: Targets | None = None,
) -> dict[str, Any]:
    """Score ``results_rows`` against the ground truth of ``split`` (see the module docstring)."""
    errs, scene_ids, ignored = instance_errors(
        dataset_root, results_rows, split, scenes, points, targets
    )
    objects = {}
    for obj_id, e in errs.items():
        objects[str(obj_id)] = {"symmetric": e.symmetric, **_summary([e])}
    return {
        "dataset": str(dataset_root),
        "split": split,
        "scenes": scene_ids,
        "points": str(points),
        "objects": objects,
        "all": _summary(list(errs.values())),
        "mean_of_objects": _mean_of_objects(objects),
        "ignored_rows": ignored,
    }


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

    rows = read_results_csv(args.results)
    targets = read_targets(args.targets) if args.targets is not None else None
    report = evaluate(
        args.dataset, rows, args.split, args.scenes, points=args.points, targets=targets
    )
    print(format_table(report))
    if report["ignored_rows"]:
        print(f"({report['ignored_rows']} result rows matched no ground-truth instance)")
    if args.json is not None:
        with lock_output_path(args.json, "chpf-eval"):
            atomic_write_text(args.json, json.dumps(report, indent=2) + "\n")
    return 0


cli = run_main(main)
