"""``chpf-quantize``: add int8 encoders to a model bundle (``export.quantize``).

Example::

    chpf-quantize --bundle bundles/mug --dataset data/mug_seq     # crops from your sequences
    chpf-quantize --bundle bundles/duck --dataset data/seq --obj-id 5   # the dataset's id of it
    chpf-quantize --bundle chpf/assets/bundles/box                # the shipped demo's crops
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from chpf import __version__
from chpf.console import run_main
from chpf.errors import BundleError
from chpf.outdir import lock_output_path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="chpf-quantize",
        description="Add int8 encoders to a model bundle, calibrated on real crops and checked "
        "against float32 (nothing is written if they disagree).",
    )
    p.add_argument("--bundle", required=True, type=Path, help="model bundle folder (changed)")
    p.add_argument(
        "--dataset",
        type=Path,
        help="BOP dataset with ground truth of the bundle's object (default: the shipped demo "
        "sequence when it shows that object)",
    )
    p.add_argument(
        "--obj-id",
        type=int,
        help="the dataset's obj_id of the bundle's object (default: the bundle's own)",
    )
    p.add_argument("--crops", type=int, default=1024, help="crops: half calibrate, half check")
    p.add_argument("--min-cosine", type=float, default=0.99, help="int8 vs float32 agreement")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    p.add_argument("--version", action="version", version=f"chpf-quantize {__version__}")
    return p


def main(argv: list[str] | None = None) -> int:
    """Quantise the bundle's encoders; returns 0 (errors raise ChpfError: one line, exit 2)."""
    args = build_parser().parse_args(argv)
    from chpf.bundle import Bundle
    from chpf.tracking.demo import demo_dataset
    from export.quantize import calibration_crops, quantize_bundle

    bundle = Bundle.load(args.bundle, threads=args.threads)
    if args.dataset is not None:
        dataset, source = args.dataset, str(args.dataset.resolve())
    else:
        dataset = demo_dataset(bundle)
        source = f"the shipped demo sequence ({dataset.name})"
    if args.crops < 16:
        raise BundleError(f"--crops {args.crops}: at least 16 (half calibrate, half check)")
    t0 = time.perf_counter()
    with lock_output_path(args.bundle, "chpf-quantize"):
        crops = calibration_crops(dataset, bundle, args.crops, obj_id=args.obj_id)
        report = quantize_bundle(args.bundle, crops, args.min_cosine, args.threads, source=source)
    for key, name in report.files.items():
        print(f"{args.bundle / name}: {key}, min cosine to float32 {report.min_cosine[key]:.4f}")
    print(
        f"int8 encoders calibrated on {report.crops[0]} crops of {source}, checked on "
        f"{report.crops[1]}, in {time.perf_counter() - t0:.1f} s; use them with "
        "--set runtime.precision=int8"
    )
    return 0


cli = run_main(main)
