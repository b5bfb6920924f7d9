"""``chpf-gen-data``: synthetic training pairs, autoencoder samples and BOP test sequences.

Subcommands::

    chpf-gen-data pairs --object mug --out data/mug_pairs --n 100000 [--workers 2]
    chpf-gen-data ae    --object mesh.ply --unit mm --out data/ae --n 50000 [--allow-size]
    chpf-gen-data pool  --object mug                 # build / report the cached pools only
    chpf-gen-data sequences --objects mug,can,box --out data/seq [--occlusion heavy]
    chpf-gen-data bench [--object mug --n 4000]       # samples/s with 1 and 2 workers
    chpf-gen-data contact-sheet DIR --out sheet.png   # look at pairs / ae / a sequence

Configuration: ``--config configs/gen_default.yaml`` (every key documented there) and
``--set section.key=value`` overrides. Errors print one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from chpf.console import run_main
from chpf.errors import ConfigError
from chpf.objects import MESH_UNITS
from chpf.outdir import check_out_dir, check_out_file, lock_output_path
from data_gen import config as C


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="YAML config (see configs/gen_default.yaml)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one config value (repeatable)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed = same bytes)")
    p.add_argument(
        "--overwrite", action="store_true", help="replace an output folder made with another config"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_unit(p: argparse.ArgumentParser, what: str = "a mesh file") -> None:
    p.add_argument("--unit", choices=list(MESH_UNITS), default="m", help=f"unit of {what}")
    p.add_argument(
        "--allow-size",
        action="store_true",
        help="accept a mesh whose diameter is outside 1 cm - 2 m (default: refuse, naming the "
        "unit that fits)",
    )


def _add_object(p: argparse.ArgumentParser) -> None:
    p.add_argument("--object", required=True, help="built-in name (mug, box, can, drill) or mesh")
    _add_unit(p)
    p.add_argument("--size", type=int, help="crop size S (overrides crop.size)")
    p.add_argument("--codebook-size", type=int, help="codebook grid entries (codebook.size)")
    p.add_argument(
        "--cache-dir",
        type=Path,
        help="pool cache (default $CHPF_CACHE/pools or ~/.cache/chpf/pools)",
    )
    p.add_argument("--workers", type=int, default=1, help="local worker processes")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="chpf-gen-data", description=__doc__.split("\n")[0].replace("``", "")
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    for kind, what in (("pairs", "classifier pairs"), ("ae", "autoencoder samples")):
        p = sub.add_parser(kind, help=f"{what} as shards + manifest")
        _add_object(p)
        _add_common(p)
        p.add_argument("--out", type=Path, required=True, help="output folder")
        p.add_argument("--n", type=int, required=True, help="number of samples")
        p.add_argument("--samples-per-shard", type=int, help="overrides shards.samples_per_shard")
        p.add_argument("--shard", type=int, help="index I of this job (with --num-shards M)")
        p.add_argument("--num-shards", type=int, default=1, help="number M of jobs")

    p = sub.add_parser("pool", help="build (or find) the cached pools of an object")
    _add_object(p)
    _add_common(p)
    p.add_argument(
        "--kind",
        choices=["pairs", "ae"],
        default="pairs",
        help="pools needed by this kind (pairs also needs the codebook pool)",
    )

    p = sub.add_parser("sequences", help="BOP test sequences + simulated detections")
    _add_common(p)
    p.add_argument(
        "--objects",
        required=True,
        help="comma-separated objects; the first is the target, others distractors",
    )
    _add_unit(p, "mesh files")
    p.add_argument("--out", type=Path, required=True, help="BOP dataset root to write")
    p.add_argument("--split", default="test", help="split folder name")
    p.add_argument("--num-scenes", type=int, help="sequences.num_scenes")
    p.add_argument("--frames", type=int, help="sequences.frames")
    p.add_argument("--occlusion", choices=["none", "partial", "heavy"], help="sequences.occlusion")
    p.add_argument("--width", type=int, help="sequences.width")
    p.add_argument("--height", type=int, help="sequences.height")

    p = sub.add_parser("bench", help="samples/s of pairs and ae with 1 and 2 workers")
    p.add_argument("--object", default="mug")
    p.add_argument("--n", type=int, default=4000, help="samples per timed run")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    p.add_argument(
        "--cache-dir",
        type=Path,
        help="pool cache to use (default: a fresh temporary one, so that the pool build is timed)",
    )
    p.add_argument("--config", type=Path)
    p.add_argument("--set", action="append", default=[])

    p = sub.add_parser("contact-sheet", help="PNG contact sheet of a pairs/ae/sequence folder")
    p.add_argument("dir", type=Path, help="pairs/ae output folder, or BOP root / scene folder")
    p.add_argument("--out", type=Path, required=True, help="PNG file to write")
    p.add_argument("--n", type=int, default=24, help="samples / frames to show")
    p.add_argument("--scene", type=int, help="scene id (BOP root)")
    return ap


def _config(args: argparse.Namespace, overrides: dict) -> dict:
    sets = list(args.set)
    for key, value in overrides.items():
        if value is not None:
            sets.append(f"{key}={value}")
    return C.load_config(args.config, sets)


def _positive(name: str, value: int | None, minimum: int = 1) -> None:
    if value is not None and value < minimum:
        raise ConfigError(f"{name} must be >= {minimum}, got {value}")


def check_shard_args(shard: int | None, num_shards: int) -> None:
    """ConfigError unless ``--shard I --num-shards M`` name one job of M (or neither is given)."""
    _positive("--num-shards", num_shards)
    if shard is not None and not 0 <= shard < num_shards:
        raise ConfigError(f"--shard must be in 0..{num_shards - 1}, got {shard}")
    if shard is None and num_shards > 1:
        raise ConfigError("--num-shards needs --shard I")


def _cmd_samples(args: argparse.Namespace) -> int:
    from chpf.crops import CropSpec
    from data_gen.compose import ComposerContext
    from data_gen.generate import generate
    from data_gen.mesh_checks import checked_object

    _positive("--n", args.n)
    _positive("--workers", args.workers)
    check_shard_args(args.shard, args.num_shards)
    cfg = _config(
        args,
        {
            "crop.size": args.size,
            "codebook.size": args.codebook_size,
            "shards.samples_per_shard": args.samples_per_shard,
        },
    )
    obj = checked_object(args.object, unit=args.unit, allow_size=args.allow_size)
    spec = CropSpec.for_object(obj.diameter, cfg["crop"]["size"])
    ctx = ComposerContext(
        obj=obj,
        spec=spec,
        cfg=cfg,
        cache_dir=str(args.cache_dir) if args.cache_dir else None,
        kind=args.cmd,
    )
    res = generate(
        ctx,
        args.out,
        args.n,
        args.seed,
        args.shard,
        args.num_shards,
        args.workers,
        args.overwrite,
        progress=not args.no_progress,
    )
    rate = res.samples / res.seconds if res.seconds > 0 else 0.0
    print(
        f"{args.cmd}: wrote {len(res.written)} shards ({res.samples} samples, "
        f"{rate:.0f}/s), {len(res.skipped)} already complete -> {args.out}"
    )
    return 0


def _cmd_pool(args: argparse.Namespace) -> int:
    from chpf.crops import CropSpec
    from data_gen.compose import ComposerContext, build_pools
    from data_gen.mesh_checks import checked_object

    _positive("--workers", args.workers)
    cfg = _config(args, {"crop.size": args.size, "codebook.size": args.codebook_size})
    obj = checked_object(args.object, unit=args.unit, allow_size=args.allow_size)
    spec = CropSpec.for_object(obj.diameter, cfg["crop"]["size"])
    ctx = ComposerContext(
        obj, spec, cfg, str(args.cache_dir) if args.cache_dir else None, args.kind
    )
    t0 = time.perf_counter()
    setup = build_pools(ctx, workers=args.workers, progress=not args.no_progress)
    dt = time.perf_counter() - t0
    for name in ("codebook", "obs", "occluder"):
        path = getattr(setup, f"{name}_dir")
        if path is not None:
            print(f"{name} pool: {path}")
    print(f"pools ready in {dt:.1f} s")
    return 0


def _cmd_sequences(args: argparse.Namespace) -> int:
    from data_gen.sequences import generate_sequences

    cfg = _config(
        args,
        {
            "sequences.num_scenes": args.num_scenes,
            "sequences.frames": args.frames,
            "sequences.occlusion": args.occlusion,
            "sequences.width": args.width,
            "sequences.height": args.height,
        },
    )
    names = [s.strip() for s in args.objects.split(",") if s.strip()]
    if not names:
        raise ConfigError("--objects: give at least one object")
    generate_sequences(
        names,
        args.out,
        cfg,
        args.seed,
        split=args.split,
        unit=args.unit,
        overwrite=args.overwrite,
        progress=not args.no_progress,
        allow_size=args.allow_size,
    )
    print(
        f"sequences: {cfg['sequences']['num_scenes']} scenes x "
        f"{cfg['sequences']['frames']} frames -> {args.out}"
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from data_gen.bench import run_bench

    workers = [int(w) for w in args.workers.split(",") if w.strip()]
    run_bench(args.object, args.n, args.size, workers, args.cache_dir, args.config, args.set)
    return 0


def _cmd_contact_sheet(args: argparse.Namespace) -> int:
    from data_gen.contact_sheet import contact_sheet

    path = contact_sheet(args.dir, args.out, n=args.n, scene_id=args.scene)
    print(f"contact sheet -> {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point (argv without the program name)."""
    args = build_parser().parse_args(argv)
    if args.cmd in ("pairs", "ae", "sequences"):
        check_out_dir(args.out)
    elif args.cmd == "contact-sheet":
        check_out_file(args.out)
    cmd = {
        "pairs": _cmd_samples,
        "ae": _cmd_samples,
        "pool": _cmd_pool,
        "sequences": _cmd_sequences,
        "bench": _cmd_bench,
        "contact-sheet": _cmd_contact_sheet,
    }[args.cmd]
    if args.cmd in ("pairs", "ae", "sequences"):  # one writer per output (per shard job) at a time
        out = args.out
        if getattr(args, "shard", None) is not None:  # the jobs of an array run side by side
            out = out.parent / f"{out.name}.shard-{args.shard}-of-{args.num_shards}"
        with lock_output_path(out, f"chpf-gen-data {args.cmd}"):
            return cmd(args)
    return cmd(args)


cli = run_main(main)

if __name__ == "__main__":
    sys.argv[0] = "chpf-gen-data"
    cli()
