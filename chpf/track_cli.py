"""``chpf-track``: track an object through a BOP dataset with CH-PF and the baselines.

Usage::

    chpf-track --bundle B --dataset BOP_DIR [--split test] [--scenes 1,2]
               [--method chpf|srl|augmcl|annealing|e2e|poserbpf|poserbpf++|fixed|none|all|a,b]
               [--modality rgb|rgbd] [--detections FILE] [--out DIR] [--config YAML] [--seed 0]
               [--set section.key=value ...]
    chpf-track --demo [--bundle B] [--out DIR]

Writes to ``--out``: per method a BOP result CSV (``METHOD_DATASET-SPLIT.csv``, readable by
``chpf-eval``) and a frame log (``log_METHOD.csv``: alpha, sum L, sum C, ESS, errors, ms per
stage), both flushed frame by frame (a rerun resumes); ``plots/scene_XXXXXX.png`` (ADD-S error
and alpha over time); and, when the dataset has ground truth, prints the ADD / ADD-S AUC table.
The first output line says where the detection boxes come from.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from chpf.atomic import atomic_write_text
from chpf.bop import BopDataset, read_results_csv
from chpf.bundle import Bundle
from chpf.console import run_main, scene_list
from chpf.errors import BundleError, ConfigError, DatasetError
from chpf.model_points import model_points
from chpf.outdir import check_out_dir, claim_settings, lock_output_dir
from chpf.tracking.boxes import make_box_source
from chpf.tracking.config import MODALITIES, make_config
from chpf.tracking.methods import method_names
from chpf.tracking.run_dataset import MethodRun, run_dataset
from chpf.tracking.run_record import SETTINGS_FILE, clear_outputs, track_settings
from chpf.tracking.runlog import NETWORK_STAGES
from chpf.tracking.tracker import Tracker


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
        description="Track one object through a BOP dataset with CH-PF and baselines.",
    )
    p.add_argument(
        "--demo",
        action="store_true",
        help="track the shipped short occluded sequence of the shipped bundle's object with "
        "CH-PF, CH-RBPF, SRL and PoseRBPF",
    )
    p.add_argument("--bundle", type=Path, help="model bundle folder (default for --demo: shipped)")
    p.add_argument("--dataset", type=Path, help="BOP dataset root")
    p.add_argument("--split", default="test", help="split folder (default: test)")
    p.add_argument("--scenes", type=scene_list, default=None, help="e.g. 48,49 (default: all)")
    p.add_argument("--method", default="chpf", help="a method, a comma list, or 'all'")
    p.add_argument("--modality", default="rgb", choices=MODALITIES)
    p.add_argument(
        "--detections",
        type=Path,
        default=None,
        help="BOP detections JSON (default: the simulated detector)",
    )
    p.add_argument("--out", type=Path, default=None, help="output folder (default: chpf_track_out)")
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
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-plot", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _dataset_obj_ids(ds: BopDataset, split: str, scenes: list[int]) -> set[int]:
    ids: set[int] = set()
    for sid in scenes:
        for poses in ds.scene(split, sid).gt.values():
            ids.update(p.obj_id for p in poses)
    if not ids and ds.models_info_path.is_file():
        ids = set(ds.models_info())
    return ids


def auc_table(dataset: Path, runs: dict[str, MethodRun], split: str, scenes: list[int]) -> str:
    """ADD / ADD-S AUC per method (chpf.eval_cli.evaluate) plus speed, as a text table."""
    from chpf.eval_cli import evaluate, format_auc

    head = f"{'method':<11} {'frames':>6} {'missing':>7} {'ADD AUC':>8} {'ADD-S AUC':>9} {'fps':>6}"
    lines = [head, "-" * len(head)]
    for m, run in runs.items():
        rows = read_results_csv(run.results)
        rep = evaluate(dataset, rows, split=split, scenes=scenes)["all"]
        fps = "-" if run.frames == 0 else f"{run.fps:.1f}"
        lines.append(
            f"{m:<11} {rep['n']:>6d} {rep['n_missing']:>7d} {format_auc(rep['add_auc']):>8} "
            f"{format_auc(rep['adds_auc']):>9} {fps:>6}"
        )
    return "\n".join(lines)


def stage_table(runs: dict[str, MethodRun]) -> str:
    """Mean ms per stage of the newly tracked frames, and the non-network share."""
    stages = ["crop", "encode", "ch_encode", "lookup", "head", "depth", "estimate", "resample"]
    head = f"{'method':<11}" + "".join(f" {s:>9}" for s in stages) + f" {'total':>8} {'non-net':>8}"
    lines = [head]
    for m, run in runs.items():
        if run.frames == 0:
            continue
        mean = {k: v / run.frames for k, v in run.stage_ms.items()}
        total = mean.get("total", 0.0)
        net = sum(mean.get(s, 0.0) for s in NETWORK_STAGES)
        share = (total - net) / total if total > 0 else float("nan")
        cells = "".join(f" {mean[s]:>9.2f}" if s in mean else f" {'-':>9}" for s in stages)
        lines.append(f"{m:<11}{cells} {total:>8.1f} {share:>8.0%}")
    return "\n".join(lines)


def track(
    args: argparse.Namespace, methods: list[str], dataset: Path, bundle: Bundle, fresh: bool = False
) -> int:
    """Run the methods on the dataset and report (shared by --dataset and --demo).

    ``--out`` is locked while the run writes; its recorded settings must match this run's (see
    chpf.tracking.run_record) unless ``--overwrite``; ``fresh`` clears its outputs first."""
    ds = BopDataset(dataset)
    scenes = ds.scene_ids(args.split)
    if args.scenes is not None:
        missing = sorted(set(args.scenes) - set(scenes))
        if missing:
            raise DatasetError(f"{ds.split_path(args.split)}: no scene(s) {missing}")
        scenes = [s for s in scenes if s in set(args.scenes)]
    boxes = make_box_source(ds, args.split, args.detections, args.seed)
    obj_id = bundle.obj_info.obj_id
    ids = _dataset_obj_ids(ds, args.split, scenes)
    if ids and obj_id not in ids:
        raise BundleError(
            f"{bundle.path}: bundle is for object {bundle.obj_info.name!r} (obj_id {obj_id}) but "
            f"{dataset} has obj_ids {sorted(ids)}"
        )
    bundle.check_dataset(ds)
    cfg = tracking_config(args)
    trackers = {
        m: Tracker(bundle, method=m, modality=args.modality, seed=args.seed, config=cfg)
        for m in methods
    }
    out = args.out
    with lock_output_dir(out, "chpf-track"):
        settings = track_settings(
            bundle,
            dataset,
            args.split,
            scenes,
            args.detections,
            methods,
            args.modality,
            args.seed,
            cfg,
        )
        if claim_settings(out, SETTINGS_FILE, settings, args.overwrite or fresh) or fresh:
            clear_outputs(out)
        print(boxes.description, flush=True)
        points = None
        has_gt = any(ds.scene(args.split, s).gt for s in scenes)
        if has_gt:
            try:
                points = model_points(ds, obj_id)
            except Exception as err:  # no mesh: track anyway, without per-frame errors
                print(f"note: no per-frame errors ({err})")
        print(
            f"tracking obj_id {obj_id} ({bundle.obj_info.name}) in {len(scenes)} scene(s) with "
            f"{', '.join(methods)} [{args.modality}, N={cfg.filter.n_particles}] -> {out}",
            flush=True,
        )
        runs = run_dataset(
            trackers,
            ds,
            args.split,
            scenes,
            obj_id,
            boxes,
            out,
            args.seed,
            points,
            progress=not args.no_progress,
        )
        print(stage_table(runs))
        summary = {
            m: {"results": str(r.results), "log": str(r.log), "fps": r.fps} for m, r in runs.items()
        }
        if has_gt:
            table = auc_table(dataset, runs, args.split, scenes)
            print(table)
            atomic_write_text(out / "auc_table.txt", table + "\n")
        if not args.no_plot:
            from chpf.tracking.plots import plot_scenes

            pngs = plot_scenes(
                {m: r.log for m, r in runs.items()}, out / "plots", bundle.obj_info.name
            )
            for p in pngs:
                print(f"plot: {p}")
        atomic_write_text(out / "runs.json", json.dumps(summary, indent=1) + "\n")
        return 0


def tracking_config(args: argparse.Namespace) -> Any:
    """The TrackConfig of --config, --set and --n-particles (ConfigError naming the key)."""
    n = {} if args.n_particles is None else {"filter": {"n_particles": args.n_particles}}
    return make_config(args.config, args.set, **n)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``chpf-track``; returns the exit code."""
    args = build_parser().parse_args(argv)
    args.out = check_out_dir(args.out or Path("chpf_demo" if args.demo else "chpf_track_out"))
    run_cfg = tracking_config(args).runtime
    if args.demo:
        from chpf.tracking.demo import DEMO_METHODS, demo_dataset, shipped_bundle

        bundle = Bundle.load(args.bundle or shipped_bundle(), run_cfg.threads, spin=run_cfg.spin)
        dataset = demo_dataset(bundle)
        if args.modality != "rgb":
            raise ConfigError(f"{dataset}: the demo sequence is RGB only (no depth frames)")
        args.detections = None
        args.split = "test"
        methods = list(DEMO_METHODS) if args.method == "chpf" else parse_methods(args.method)
        return track(args, methods, dataset, bundle, fresh=True)  # the demo starts afresh
    if args.bundle is None or args.dataset is None:
        raise ConfigError("chpf-track needs --bundle and --dataset (or --demo)")
    methods = parse_methods(args.method)
    bundle = Bundle.load(args.bundle, run_cfg.threads, spin=run_cfg.spin)
    return track(args, methods, args.dataset, bundle)


cli = run_main(main)

if __name__ == "__main__":
    cli()
