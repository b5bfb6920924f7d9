"""``chpf-export``: trained checkpoints -> a model bundle folder that the runtime loads.

Example::

    chpf-export --ae runs/ae/best.ckpt --ch runs/ch/best.ckpt --object mug --out bundles/mug
"""

from __future__ import annotations

import argparse
import time

from chpf import __version__
from chpf.console import run_main
from chpf.objects import MESH_UNITS
from chpf.outdir import check_out_dir, lock_output_path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="chpf-export",
        description="Export an autoencoder and a CH classifier checkpoint, with a codebook over "
        "a uniform SO(3) grid, into a model bundle (ONNX + codebook.npz + manifest.json).",
    )
    p.add_argument("--ae", required=True, help="autoencoder checkpoint (.ckpt from chpf-train ae)")
    p.add_argument("--ch", required=True, help="CH classifier checkpoint (chpf-train ch)")
    p.add_argument("--object", required=True, help="built-in object name or mesh file")
    p.add_argument("--out", required=True, help="bundle folder to write")
    p.add_argument("--config", help="export YAML config (flags below override it)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one key of the export config, e.g. parity_tol=0.001 (repeatable)",
    )
    p.add_argument("--codebook-size", type=int, help="K codebook entries (default 20000)")
    p.add_argument("--threads", type=int, help="onnxruntime threads during export (default 2)")
    p.add_argument("--workers", type=int, help="render processes for the codebook (default 2)")
    p.add_argument("--cache-dir", help="render pool cache folder (default: data_gen's)")
    p.add_argument("--unit", choices=list(MESH_UNITS), help="unit of a mesh file (default m)")
    p.add_argument(
        "--obj-id",
        type=int,
        help="the bundle's dataset obj_id (default: from a BOP model name such as "
        "obj_000005.ply, a built-in's own, else 0)",
    )
    p.add_argument(
        "--allow-size",
        action="store_true",
        help="accept a mesh whose diameter is outside 1 cm - 2 m (default: refuse)",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace a bundle of another object in --out"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--version", action="version", version=f"chpf-export {__version__}")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the export; returns 0 (errors raise ChpfError, printed as one line by ``cli``)."""
    args = build_parser().parse_args(argv)
    check_out_dir(args.out)  # before the checkpoints are read and the codebook rendered
    # heavy imports (torch) after argument parsing so --help stays fast
    from chpf.config_schema import load
    from export.config import ExportConfig
    from export.pipeline import export_bundle

    if args.config:
        cfg = ExportConfig.from_yaml(args.config, args.set)
    else:
        cfg = load(ExportConfig, sets=args.set)
    overrides = {
        "codebook_size": args.codebook_size,
        "threads": args.threads,
        "workers": args.workers,
        "cache_dir": args.cache_dir,
        "unit": args.unit,
        "obj_id": args.obj_id,
    }
    flags = {k: v for k, v in overrides.items() if v is not None}
    cfg = load(ExportConfig, data=flags, base=cfg, where="command line")
    t0 = time.perf_counter()
    with lock_output_path(args.out, "chpf-export"):
        res = export_bundle(
            args.ae,
            args.ch,
            args.object,
            args.out,
            cfg,
            overwrite=args.overwrite,
            progress=not args.quiet,
            allow_size=args.allow_size,
        )
    m = res.manifest
    worst = max(res.parity.values())
    print(
        f"wrote {res.out}: object {m['object']['name']} (obj_id {m['object']['obj_id']}), "
        f"S={m['crop']['size']}, "
        f"E={m['embedding_dim']}, K={m['codebook_size']}, "
        f"shared encoder={m['ch_shares_ae_encoder']}, parity max |diff| {worst:.2e}, "
        f"{time.perf_counter() - t0:.1f} s"
    )
    return 0


cli = run_main(main)
