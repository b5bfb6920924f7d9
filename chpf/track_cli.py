"""``chpf-track``: track an object through a BOP dataset, an image folder or a video with CH-PF
and the baselines.

Usage::

    chpf-track --bundle B [--bundle B2 ...] --dataset BOP_DIR [--obj-id N ...] [--split test]
               [--scenes 1,2] [--detections JSON]
    chpf-track --bundle B [--bundle B2 ...] (--images DIR [--depth DIR] [--depth-scale MM] |
               --video FILE) --camera FILE (--init-box x,y,w,h ... | --detections CSV_OR_JSON)
               [--fps 30]
    chpf-track --demo [--object box|mug | --bundle B] [--out DIR]
    common: [--method chpf|srl|augmcl|annealing|e2e|poserbpf|poserbpf++|fixed|none|all|a,b]
            [--modality rgb|rgbd] [--out DIR] [--config YAML] [--seed 0] [--set key=value ...]
            [--overlay FILE.mp4|DIR] [--poses FILE.jsonl]

Writes to ``--out``: per method a BOP result CSV (``METHOD_DATASET-SPLIT.csv``, readable by
``chpf-eval``; an image folder or video is scene 1 of dataset NAME, split ``images`` / ``video``)
and a frame log (``log_METHOD.csv``: alpha, sum L, sum C, ESS, errors, ms per stage), both
flushed frame by frame (a rerun resumes); ``plots/scene_XXXXXX.png`` (ADD-S error and alpha over
time); and, when the dataset has ground truth, prints the ADD / ADD-S AUC table. ``--overlay``
and ``--poses`` write the estimates drawn on the frames and one JSON line per frame
(``chpf.tracking.overlay``, ``chpf.tracking.pose_stream``). The first output line says where
the detection boxes come from.

Several objects: ``--bundle`` repeated tracks each bundle's object through the same frames
(each frame is read once; ``chpf.tracking.multi.MultiTracker``). On a BOP dataset each bundle
tracks its obj_id (``--obj-id``, if given, once per ``--bundle``, in the same order); on an
image folder or video ``--init-box`` is given once per ``--bundle``, in order (or a BOP
detections JSON, matched by obj_id). The obj_ids must differ (``--obj-id`` tells two copies of
a bundle apart). The result CSV of a method holds every object's rows (BOP CSVs carry the
obj_id); logs are per object (``log_METHOD_objN.csv``), and so are the plots
(``plots/objN/``), the tables' rows (``METHOD obj N``), the ``--poses`` lines and the bars of
the ``--overlay``, which draws every object on each frame.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.bop import BopDataset, read_results_csv
from chpf.bundle import PRECISIONS, Bundle
from chpf.console import run_main, scene_list
from chpf.errors import BundleError, ConfigError, DatasetError
from chpf.model_points import model_points
from chpf.outdir import check_out_dir, check_out_file, claim_settings, lock_output_dir
from chpf.providers import DEVICES, describe
from chpf.sources.boxes import parse_box
from chpf.sources.frame import FrameSource
from chpf.tracking.boxes import make_box_source
from chpf.tracking.config import MODALITIES, make_config
from chpf.tracking.methods import method_names
from chpf.tracking.multi import MultiTracker
from chpf.tracking.overlay import check_overlay_target
from chpf.tracking.run_dataset import (
    DEFAULT_FPS,
    FrameSink,
    MethodRun,
    bop_sequences,
    run_sequences,
)
from chpf.tracking.run_record import (
    SETTINGS_FILE,
    bop_inputs,
    clear_outputs,
    file_record,
    track_settings,
)
from chpf.tracking.runlog import NETWORK_STAGES
from chpf.tracking.search_region import BOX_SOURCES
from chpf.tracking.tracker import Tracker

SEARCH_NOTES = {
    "auto": "search.box_source auto: a frame without a box is searched around the estimate "
    "until a detector runs (a box after the first), then predict-only",
    "detections": "search.box_source detections: a frame without a box is predict-only",
    "estimate": "search.box_source estimate: after the first box every frame is searched "
    "around the estimate, boxes ignored",
}
"""What the run's first line says about frames without a box (chpf.tracking.search_region)."""


def parse_methods(text: str) -> list[str]:
    """'all' -> the paper's methods; else a comma-separated list of registered methods."""
    if text == "all":
        return list(method_names(paper_only=True))
    methods = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in methods if m not in method_names()]
    if bad or not methods:
        raise ConfigError(
            f"--method: unknown {bad or text!r} (choose from {', '.join(method_names())}, all)"
        )
    return list(dict.fromkeys(methods))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="chpf-track",
        description="Track one object (or several: --bundle repeated) through a BOP dataset, an "
        "image folder or a video with CH-PF and baselines.",
    )
    p.add_argument(
        "--demo",
        action="store_true",
        help="track the shipped short occluded sequence of the shipped bundle's object with "
        "CH-PF, CH-RBPF, SRL and PoseRBPF",
    )
    p.add_argument(
        "--object",
        default=None,
        help="with --demo: the shipped bundle and sequence of this object (box, mug; default box)",
    )
    p.add_argument(
        "--bundle",
        type=Path,
        action="append",
        default=None,
        help="model bundle folder (default for --demo: shipped); repeat it to track several "
        "objects at once",
    )
    p.add_argument("--dataset", type=Path, help="BOP dataset root")
    p.add_argument(
        "--obj-id",
        type=int,
        action="append",
        default=None,
        help="the dataset's obj_id of the bundle's object (default: the bundle's own); with "
        "several --bundle, once per bundle in the same order",
    )
    p.add_argument("--split", default="test", help="split folder (default: test)")
    p.add_argument("--scenes", type=scene_list, default=None, help="e.g. 48,49 (default: all)")
    p.add_argument(
        "--images", type=Path, default=None, help="folder of image files (sorted by name)"
    )
    p.add_argument(
        "--depth", type=Path, default=None, help="with --images: folder of as many depth images"
    )
    p.add_argument(
        "--depth-scale",
        type=float,
        default=None,
        help="mm per depth unit of --depth (default: the camera file's depth_scale, else 1)",
    )
    p.add_argument("--video", type=Path, default=None, help="a video file OpenCV can read")
    p.add_argument(
        "--camera",
        type=Path,
        default=None,
        help="with --images / --video: camera file (JSON or YAML with K or fx, fy, cx, cy; "
        "OpenCV calibration YAML); width and height, if given, are checked",
    )
    p.add_argument(
        "--init-box",
        type=parse_box,
        action="append",
        default=None,
        metavar="X,Y,W,H",
        help="with --images / --video: the object's box in the first frame (pixels); with "
        "several --bundle, once per bundle in the same order",
    )
    p.add_argument(
        "--fps",
        type=float,
        default=DEFAULT_FPS,
        help="frame rate of inputs that record none (images, BOP), for the frame times and the "
        f"overlay video (default {DEFAULT_FPS:g})",
    )
    p.add_argument("--method", default="chpf", help="a method, a comma list, or 'all'")
    p.add_argument("--modality", default="rgb", choices=MODALITIES)
    p.add_argument(
        "--device",
        choices=DEVICES,
        default=None,
        help="where the networks run: auto (GPU if onnxruntime-gpu sees one), cpu, cuda "
        "(default: the config's runtime.device, auto)",
    )
    p.add_argument(
        "--precision",
        choices=PRECISIONS,
        default=None,
        help="the encoders': float32 or int8 (a bundle made by chpf-quantize; default: the "
        "config's runtime.precision, float32)",
    )
    p.add_argument(
        "--detections",
        type=Path,
        default=None,
        help="BOP detections JSON (default: the simulated detector); with --images / --video "
        "also a CSV frame,x,y,w,h[,score]",
    )
    p.add_argument("--out", type=Path, default=None, help="output folder (default: chpf_track_out)")
    p.add_argument(
        "--overlay",
        type=Path,
        default=None,
        help="draw the estimate on every frame: a video (.mp4, .avi, .mov, .mkv) or a folder "
        "of PNGs",
    )
    p.add_argument(
        "--poses",
        type=Path,
        default=None,
        help="stream one JSON line per frame, method and object (R, t in metres, alpha, ESS) "
        "to this file",
    )
    p.add_argument("--config", type=Path, default=None, help="tracking options YAML")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the outputs in --out made with other settings (default: refuse)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one tracking option, e.g. srl.beta=0.5 (repeatable)",
    )
    p.add_argument(
        "--n-particles", type=int, default=None, help="particles (filter.n_particles, default 50)"
    )
    p.add_argument(
        "--box-source",
        choices=BOX_SOURCES,
        default=None,
        help="the box of a frame (search.box_source, default auto): auto = its detection, else "
        "a search region around the estimate that widens while the filter doubts (predict "
        "only once a box has come after the first); "
        "detections = its detection only (none: predict only); estimate = the search region "
        "after the first box",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-plot", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


@dataclass
class TrackInput:
    """What a run tracks: the (scene_id, frames) sequences, named ``name`` / ``split`` in the
    result files; ``settings``: the input part of track_settings; ``boxes``: the first output
    line; ``box_origin`` names the boxes in warnings; ``what`` says what is tracked; ``points``
    {obj_id: (M,3)} for the per-frame errors (empty without ground truth); ``score``: the AUC
    table of the runs, or None (then ``no_score`` says why)."""

    name: str
    split: str
    sequences: list[tuple[int, FrameSource]]
    settings: dict[str, Any]
    boxes: str
    box_origin: str
    what: str
    fps: float
    points: dict[int, np.ndarray] = field(default_factory=dict)
    score: Callable[[dict[str, MethodRun]], str] | None = None
    no_score: str = ""


def _dataset_obj_ids(ds: BopDataset, split: str, scenes: list[int]) -> set[int]:
    ids: set[int] = set()
    for sid in scenes:
        for poses in ds.scene(split, sid).gt.values():
            ids.update(p.obj_id for p in poses)
    if not ids and ds.models_info_path.is_file():
        ids = set(ds.models_info())
    return ids


def auc_table(dataset: Path, runs: dict[str, MethodRun], split: str, scenes: list[int]) -> str:
    """ADD / ADD-S AUC per method (and object: a run with an obj_id is scored on that object's
    rows of its result CSV; chpf.eval_cli.evaluate) plus speed, as a text table."""
    from chpf.eval_cli import evaluate, format_auc

    w = max([11, *(len(m) + 1 for m in runs)])
    head = (
        f"{'method':<{w}} {'frames':>6} {'missing':>7} {'ADD AUC':>8} {'ADD-S AUC':>9} {'fps':>6}"
    )
    lines = [head, "-" * len(head)]
    for m, run in runs.items():
        rows = read_results_csv(run.results)
        if run.obj_id is not None:
            rows = [r for r in rows if r.obj_id == run.obj_id]
        rep = evaluate(dataset, rows, split=split, scenes=scenes)
        rep = rep["all"] if run.obj_id is None else rep["objects"].get(str(run.obj_id))
        if rep is None:  # no row of the object at all
            lines.append(f"{m:<{w}} {'-':>6} {'-':>7} {'-':>8} {'-':>9} {'-':>6}")
            continue
        fps = "-" if run.frames == 0 else f"{run.fps:.1f}"
        lines.append(
            f"{m:<{w}} {rep['n']:>6d} {rep['n_missing']:>7d} {format_auc(rep['add_auc']):>8} "
            f"{format_auc(rep['adds_auc']):>9} {fps:>6}"
        )
    return "\n".join(lines)


def stage_table(runs: dict[str, MethodRun]) -> str:
    """Mean ms per stage of the newly tracked frames, and the non-network share."""
    stages = ["crop", "encode", "ch_encode", "lookup", "head", "depth", "estimate", "resample"]
    w = max([11, *(len(m) + 1 for m in runs)])
    head = (
        f"{'method':<{w}}" + "".join(f" {s:>9}" for s in stages) + f" {'total':>8} {'non-net':>8}"
    )
    lines = [head]
    for m, run in runs.items():
        if run.frames == 0:
            continue
        mean = {k: v / run.frames for k, v in run.stage_ms.items()}
        total = mean.get("total", 0.0)
        net = sum(mean.get(s, 0.0) for s in NETWORK_STAGES)
        share = (total - net) / total if total > 0 else float("nan")
        cells = "".join(f" {mean[s]:>9.2f}" if s in mean else f" {'-':>9}" for s in stages)
        lines.append(f"{m:<{w}}{cells} {total:>8.1f} {share:>8.0%}")
    return "\n".join(lines)


def target_obj_ids(args: argparse.Namespace, bundles: list[Bundle]) -> list[int]:
    """The obj_ids tracked, one per bundle: --obj-id (once per --bundle, in order), else each
    bundle's own. ConfigError on a count mismatch or an obj_id given to two bundles."""
    if args.obj_id is None:
        ids = [b.obj_info.obj_id for b in bundles]
    elif len(args.obj_id) != len(bundles):
        raise ConfigError(
            f"--obj-id given {len(args.obj_id)} time(s) for {len(bundles)} --bundle: give it "
            "once per --bundle, in the same order (or not at all: each bundle's own obj_id)"
        )
    else:
        ids = [int(o) for o in args.obj_id]
    dup = sorted({o for o in ids if ids.count(o) > 1})
    if dup:
        raise ConfigError(
            f"obj_id {dup[0]} is tracked by more than one --bundle; give each its own with "
            "--obj-id N once per --bundle, in order"
        )
    return ids


def target_obj_id(args: argparse.Namespace, bundle: Bundle) -> int:
    """The obj_id tracked with one bundle: --obj-id, else the bundle's own."""
    return target_obj_ids(args, [bundle])[0]


def bop_input(args: argparse.Namespace, dataset: Path, bundles: list[Bundle]) -> TrackInput:
    """The TrackInput of a BOP dataset (--dataset, --demo): its scenes, boxes, ground truth;
    each bundle is checked against the dataset's object of its obj_id."""
    ds = BopDataset(dataset)
    scenes = ds.scene_ids(args.split)
    if args.scenes is not None:
        missing = sorted(set(args.scenes) - set(scenes))
        if missing:
            raise DatasetError(f"{ds.split_path(args.split)}: no scene(s) {missing}")
        scenes = [s for s in scenes if s in set(args.scenes)]
    obj_ids = target_obj_ids(args, bundles)
    ids = _dataset_obj_ids(ds, args.split, scenes)
    for bundle, obj_id in zip(bundles, obj_ids, strict=True):
        if ids and obj_id not in ids:
            what = f"obj_id {obj_id}" + ("" if args.obj_id is None else " by --obj-id")
            raise BundleError(
                f"{bundle.path}: bundle is for object {bundle.obj_info.name!r} ({what}) but "
                f"{dataset} has obj_ids {sorted(ids)}; pass --obj-id N to track the dataset's "
                "object N with it"
            )
        bundle.check_dataset(ds, obj_id)
    boxes = make_box_source(ds, args.split, args.detections, args.seed)
    points: dict[int, np.ndarray] = {}
    score = None
    if any(ds.scene(args.split, s).gt for s in scenes):
        for obj_id in obj_ids:
            try:
                points[obj_id] = model_points(ds, obj_id)
            except Exception as err:  # no mesh: track anyway, without per-frame errors
                print(f"note: no per-frame errors of obj_id {obj_id} ({err})")

        def score(runs: dict[str, MethodRun]) -> str:
            return auc_table(dataset, runs, args.split, scenes)

    return TrackInput(
        name=ds.root.resolve().name,
        split=args.split,
        sequences=bop_sequences(
            ds,
            args.split,
            scenes,
            obj_ids[0] if len(obj_ids) == 1 else obj_ids,
            boxes,
            args.modality == "rgbd",
            args.fps,
        ),
        settings=bop_inputs(dataset, args.split, scenes, args.detections),
        boxes=boxes.description,
        box_origin=boxes.origin,
        what=f"{len(scenes)} scene(s)",
        fps=args.fps,
        points=points,
        score=score,
        no_score=f"{dataset}: no ground truth in the tracked scenes, so no AUC table",
    )


def plain_input(args: argparse.Namespace, bundles: list[Bundle]) -> TrackInput:
    """The TrackInput of --images / --video: one sequence (scene 1), no ground truth; one
    --init-box per bundle (in order), or detections (a BOP JSON, by obj_id, for several)."""
    from chpf.sources.plain import open_plain

    path = args.images if args.images is not None else args.video
    kind = "images" if args.images is not None else "video"
    obj_ids = target_obj_ids(args, bundles)
    several = len(bundles) > 1
    if args.init_box is not None and len(args.init_box) != len(bundles):
        raise ConfigError(
            f"--init-box given {len(args.init_box)} time(s) for {len(bundles)} --bundle: give "
            "one box per --bundle, in the same order"
        )
    if several and args.detections is not None and args.detections.suffix.lower() == ".csv":
        raise ConfigError(
            f"{args.detections}: a detections CSV has no object column, so it cannot serve "
            f"{len(bundles)} --bundle; give a BOP detections JSON or one --init-box per bundle"
        )
    init: Any = None
    if args.init_box is not None:
        init = list(args.init_box) if several else args.init_box[0]
    source = open_plain(
        args.images,
        args.video,
        args.camera,
        obj_ids if several else obj_ids[0],
        args.fps,
        init_box=init,
        detections=args.detections,
        depth=args.depth,
        depth_scale=args.depth_scale,
    )
    if args.init_box is not None:
        shown = " ".join(",".join(f"{v:g}" for v in b) for b in args.init_box)
        boxes = f"detections: --init-box {shown} on the first frame only; the others have no box"
    else:
        by_frame = (
            {o: b.by_frame for o, b in source.boxes.items()}
            if isinstance(source.boxes, dict)
            else {obj_ids[0]: source.boxes.by_frame}
        )
        n = sum(len(v) for v in by_frame.values())
        boxes = f"detections: {n} boxes from {args.detections}; frames without one have no box"
    n_frames = len(source.frame_ids())
    init_rec: Any = None
    if args.init_box is not None:
        init_rec = [list(b) for b in args.init_box] if several else list(args.init_box[0])
    settings = {
        kind: str(path.resolve()),
        "depth": None if args.depth is None else str(args.depth.resolve()),
        "depth_scale": getattr(source, "depth_scale", None),
        "camera": file_record(args.camera),
        "init_box": init_rec,
        "detections": file_record(args.detections),
        "fps": source.fps,
    }
    return TrackInput(
        name=path.stem if kind == "video" else path.resolve().name,
        split=kind,
        sequences=[(1, source)],
        settings=settings,
        boxes=boxes,
        box_origin=str(args.detections or "--init-box"),
        what=f"{path} ({n_frames or 'unknown number of'} frames, {source.width}x{source.height})",
        fps=source.fps,
        no_score=f"{path}: no ground truth for an image folder or video, so no AUC table "
        "(score the result CSV with chpf-eval against a dataset that has it)",
    )


def make_sinks(
    args: argparse.Namespace,
    methods: list[str],
    bundles: list[Bundle],
    obj_ids: list[int],
    fps: float,
    cfg: Any,
) -> list[FrameSink]:
    """The --overlay and --poses writers of the run (none without those options)."""
    sinks: list[FrameSink] = []
    names = {o: b.obj_info.name for o, b in zip(obj_ids, bundles, strict=True)}
    if args.overlay is not None:
        from chpf.tracking.model_outline import outline_points
        from chpf.tracking.overlay import OverlayWriter

        n = {m: cfg.filter.n_particles for m in methods}
        points = {  # in the mesh file's frame, as the poses are (ObjectInfo.file_offset)
            o: outline_points(b) + b.obj_info.file_offset
            for o, b in zip(obj_ids, bundles, strict=True)
        }
        axes = {o: 0.5 * b.obj_info.diameter for o, b in zip(obj_ids, bundles, strict=True)}
        sinks.append(OverlayWriter(args.overlay, methods, points, axes, fps, n, names))
    if args.poses is not None:
        from chpf.tracking.pose_stream import PoseStream

        sinks.append(PoseStream(args.poses, names))
    return sinks


def track(
    args: argparse.Namespace,
    methods: list[str],
    bundles: list[Bundle],
    make_input: Callable[[], TrackInput],
    fresh: bool = False,
) -> int:
    """Run the methods on the input that ``make_input`` builds and report (shared by --dataset,
    --images / --video and --demo); several bundles are tracked together, one MultiTracker
    per method.

    ``--out`` is locked while the run writes; its recorded settings must match this run's (see
    chpf.tracking.run_record) unless ``--overwrite``; ``fresh`` clears its outputs first."""
    inp = make_input()
    obj_ids = target_obj_ids(args, bundles)
    cfg = tracking_config(args)
    trackers = {
        m: MultiTracker(
            [
                Tracker(b, method=m, modality=args.modality, seed=args.seed, config=cfg)
                for b in bundles
            ],
            obj_ids,
        )
        for m in methods
    }
    out = args.out
    with lock_output_dir(out, "chpf-track"):
        settings = track_settings(bundles, inp.settings, methods, args.modality, args.seed, cfg)
        if len(bundles) > 1:
            settings["obj_ids"] = obj_ids
        if claim_settings(out, SETTINGS_FILE, settings, args.overwrite or fresh) or fresh:
            clear_outputs(out)
        where = f"networks on the {describe(bundles[0].providers)}, {bundles[0].precision}"
        print(f"{inp.boxes} ({SEARCH_NOTES[cfg.search.box_source]}); {where}", flush=True)
        objects = " and ".join(
            f"obj_id {o} ({b.obj_info.name})" for o, b in zip(obj_ids, bundles, strict=True)
        )
        print(
            f"tracking {objects} in {inp.what} with "
            f"{', '.join(methods)} [{args.modality}, N={cfg.filter.n_particles}] -> {out}",
            flush=True,
        )
        sinks = make_sinks(args, methods, bundles, obj_ids, inp.fps, cfg)
        runs = run_sequences(
            trackers,
            inp.sequences,
            None,
            out,
            inp.name,
            inp.split,
            inp.box_origin,
            args.seed,
            inp.points or None,
            progress=not args.no_progress,
            sinks=sinks,
        )
        print(stage_table(runs))
        summary = {
            label: {"results": str(r.results), "log": str(r.log), "fps": r.fps}
            | ({} if len(bundles) == 1 else {"method": r.method, "obj_id": r.obj_id})
            for label, r in runs.items()
        }
        if inp.score is not None:
            table = inp.score(runs)
            print(table)
            atomic_write_text(out / "auc_table.txt", table + "\n")
        else:
            print(f"note: {inp.no_score}")
        if not args.no_plot:
            from chpf.tracking.plots import plot_scenes

            for o, b in zip(obj_ids, bundles, strict=True):
                mine = {r.method: r.log for r in runs.values() if r.obj_id == o}
                folder = out / "plots" / ("" if len(bundles) == 1 else f"obj{o}")
                title = b.obj_info.name + ("" if len(bundles) == 1 else f" (obj_id {o})")
                for p in plot_scenes(mine, folder, title):
                    print(f"plot: {p}")
        for what, path in (("overlay", args.overlay), ("poses", args.poses)):
            if path is not None:
                print(f"{what}: {path}")
        atomic_write_text(out / "runs.json", json.dumps(summary, indent=1) + "\n")
        return 0


def tracking_config(args: argparse.Namespace) -> Any:
    """The TrackConfig of --config, --set, --n-particles, --device and --precision
    (ConfigError naming the key)."""
    sections: dict[str, dict[str, Any]] = {}
    if args.n_particles is not None:
        sections["filter"] = {"n_particles": args.n_particles}
    if args.box_source is not None:
        sections["search"] = {"box_source": args.box_source}
    runtime = {k: getattr(args, k) for k in ("device", "precision") if getattr(args, k)}
    if runtime:
        sections["runtime"] = runtime
    return make_config(args.config, args.set, **sections)


def check_input_options(args: argparse.Namespace) -> None:
    """ConfigError (one line) on options that do not go together."""
    plain = [o for o in ("images", "video") if getattr(args, o) is not None]
    given = (["demo"] if args.demo else []) + (["dataset"] if args.dataset else []) + plain
    if len(given) > 1:
        shown = " and ".join("--" + g for g in given)
        raise ConfigError(f"chpf-track: give one input, not {shown}")
    if args.object is not None and not args.demo:
        raise ConfigError("--object: only with --demo (give --bundle otherwise)")
    if args.object is not None and args.bundle is not None:
        raise ConfigError("--demo: give --object or --bundle, not both")
    if not given:
        raise ConfigError(
            "chpf-track needs --bundle and an input: --dataset, --images or --video (or --demo)"
        )
    if not plain:
        bad = [o for o in ("camera", "init_box", "depth", "depth_scale") if getattr(args, o)]
        if bad:
            shown = ", ".join("--" + b.replace("_", "-") for b in bad)
            raise ConfigError(f"{shown}: only with --images or --video")
        return
    if args.bundle is None:
        raise ConfigError(f"--{plain[0]} needs --bundle (the model bundle of the object)")
    if args.camera is None:
        raise ConfigError(f"--{plain[0]} needs --camera FILE (the intrinsics)")
    if (args.init_box is None) == (args.detections is None):
        raise ConfigError(f"--{plain[0]} needs one of --init-box x,y,w,h or --detections FILE")
    if args.depth is not None and args.video is not None:
        raise ConfigError("--depth goes with --images (a video has no depth frames)")
    if args.modality == "rgbd" and args.depth is None:
        raise ConfigError(f"--modality rgbd needs --images with --depth DIR (got --{plain[0]})")
    if not (np.isfinite(args.fps) and args.fps > 0):
        raise ConfigError(f"--fps must be > 0, got {args.fps}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``chpf-track``; returns the exit code."""
    args = build_parser().parse_args(argv)
    check_input_options(args)
    args.out = check_out_dir(args.out or Path("chpf_demo" if args.demo else "chpf_track_out"))
    if args.overlay is not None:
        check_overlay_target(args.overlay)
    if args.poses is not None:
        check_out_file(args.poses)
    run_cfg = tracking_config(args).runtime
    loaded: dict[Path, Bundle] = {}

    def load(path: Path) -> Bundle:  # a bundle given twice is loaded once
        key = Path(path).resolve()
        if key not in loaded:
            loaded[key] = Bundle.load(
                path,
                run_cfg.threads,
                spin=run_cfg.spin,
                precision=run_cfg.precision,
                device=run_cfg.device,
            )
        return loaded[key]

    if args.demo:
        from chpf.tracking.demo import DEMO_METHODS, demo_dataset, shipped_bundle

        if args.bundle is not None and len(args.bundle) > 1:
            raise ConfigError("--demo tracks one object: give --bundle at most once")
        bundle = load(args.bundle[0] if args.bundle else shipped_bundle(args.object))
        dataset = demo_dataset(bundle)
        if args.modality != "rgb":
            raise ConfigError(f"{dataset}: the demo sequence is RGB only (no depth frames)")
        args.detections = None
        args.split = "test"
        methods = list(DEMO_METHODS) if args.method == "chpf" else parse_methods(args.method)
        return track(  # the demo starts afresh
            args, methods, [bundle], lambda: bop_input(args, dataset, [bundle]), fresh=True
        )
    if args.bundle is None:
        raise ConfigError("chpf-track needs --bundle and --dataset (or --demo)")
    methods = parse_methods(args.method)
    bundles = [load(p) for p in args.bundle]
    target_obj_ids(args, bundles)  # counts and duplicates, before anything is read
    if args.dataset is not None:
        return track(args, methods, bundles, lambda: bop_input(args, args.dataset, bundles))
    return track(args, methods, bundles, lambda: plain_input(args, bundles))


cli = run_main(main)

if __name__ == "__main__":
    cli()
