"""Benchmark of the exported networks: ``python -m export.bench``.

Prints, for the default encoder and the PoseRBPF-size one (128x128, 128-256-256-512):
ms per batch of 50 crops in torch eager and onnxruntime (1 and 2 threads), head ms for 50 pairs,
and codebook build time per 1,000 entries (cold render pool + embedding). For the default
encoder it also compares onnxruntime graph optimisation levels and dynamic int8 quantisation
(speed, and the largest change of an embedding measured as 1 - cosine).

The default encoder is the one of ``--config`` (default ``configs/train_ae.yaml``: model.encoder).
Networks are randomly initialised (seeded) unless ``--ae CKPT`` gives trained weights for the
default row; timings do not depend on the weights, the quantisation error does.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from chpf.config_schema import load, read_yaml
from chpf.console import run_main
from chpf.errors import ConfigError
from training.model_config import EncoderConfig

POSERBPF_ENCODER = EncoderConfig(channels=(128, 256, 256, 512), kernel=5, size=128)


def default_encoder(config_path: str) -> EncoderConfig:
    """The encoder config of a training YAML (model.encoder); ConfigError if it has none."""
    doc = read_yaml(config_path)
    encoder = doc.get("model", {}).get("encoder") if isinstance(doc, dict) else None
    if not isinstance(encoder, dict):
        raise ConfigError(f"{config_path}: no model.encoder")
    return load(EncoderConfig, data=encoder, where=config_path, prefix="model.encoder.")


def time_ms(fn: Callable[[], object], reps: int, warmup: int = 2, stat: str = "min") -> float:
    """Wall time of ``fn()`` in ms over ``reps`` runs after ``warmup`` runs.

    ``stat``: "min" (best run: the figure least disturbed by other processes on a shared
    machine) or "median".
    """
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return min(times) if stat == "min" else statistics.median(times)


def _crops(obj_name: str, size: int, n: int, cache_dir: Path) -> np.ndarray:
    """n real rendered crops (N,S,S,3) uint8 of a built-in object from the codebook pool."""
    from chpf.crops import CropSpec
    from chpf.objects import get_object
    from export.codebook import render_pool

    obj = get_object(obj_name)
    spec = CropSpec.for_object(obj.diameter, size=size)
    _, views = render_pool(obj, spec, n, cache_dir, progress=False)
    return np.ascontiguousarray(views.rgb)


def _codebook_seconds_per_1000(
    obj_name: str, size: int, entries: int, embed: Callable[[np.ndarray], np.ndarray]
) -> tuple[float, float]:
    """(render s, embed s) per 1,000 codebook entries, rendering into a cold (empty) cache."""
    from chpf.crops import CropSpec
    from chpf.objects import get_object
    from export.codebook import embed_all, render_pool

    obj = get_object(obj_name)
    spec = CropSpec.for_object(obj.diameter, size=size)
    with tempfile.TemporaryDirectory(prefix="chpf-bench-pool-") as cold:
        t0 = time.perf_counter()
        _, views = render_pool(obj, spec, entries, cold, workers=1, progress=False)
        t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    embed_all(embed, views.rgb, 256)
    t_embed = time.perf_counter() - t0
    scale = 1000.0 / entries
    return t_render * scale, t_embed * scale


def _row(label: str, cells: list[str], widths: list[int]) -> str:
    pairs = zip(cells, widths[1:], strict=True)
    return "  ".join([label.ljust(widths[0])] + [c.rjust(w) for c, w in pairs])


def bench_encoder(
    name: str,
    cfg: EncoderConfig,
    crops: np.ndarray,
    reps: int,
    encoder: torch.nn.Module | None = None,
) -> dict[str, Any]:
    """Timings of one encoder config (batch = len(crops)); returns a dict of results."""
    from export import onnx_export as ox
    from training.models import CHHead, Encoder

    torch.manual_seed(0)
    enc = encoder if encoder is not None else Encoder(cfg).eval()
    mod = ox.embedder_module(enc)
    onnx_bytes = ox.export_encoder(enc)
    x = torch.from_numpy(crops)
    res: dict[str, Any] = {"name": name, "onnx": onnx_bytes, "encoder": enc}
    torch.set_num_threads(2)
    with torch.inference_mode():
        res["torch"] = time_ms(lambda: mod(x), reps)
    for threads in (1, 2):
        sess = ox.make_session(onnx_bytes, threads)
        res[f"ort{threads}"] = time_ms(lambda s=sess: s.run(None, {"crops": crops}), reps)
    res["parity"] = ox.parity_error(ox.make_session(onnx_bytes, 2), mod, {"crops": crops})
    head = CHHead(enc.embedding_dim).eval()
    hb = ox.export_head(head)
    emb = ox.make_session(onnx_bytes, 2).run(None, {"crops": crops})[0]
    cand = np.ascontiguousarray(emb[::-1])
    hm = ox.head_module(head)
    with torch.inference_mode():
        te, tc = torch.from_numpy(emb), torch.from_numpy(cand)
        res["head_torch"] = time_ms(lambda: hm(te, tc), max(reps, 50))
    for threads in (1, 2):
        hs = ox.make_session(hb, threads)
        res[f"head_ort{threads}"] = time_ms(
            lambda s=hs: s.run(None, {"obs": emb, "cand": cand}), max(reps, 50)
        )
    return res


def bench_variants(onnx_bytes: bytes, crops: np.ndarray, reps: int) -> list[tuple[str, ...]]:
    """Graph optimisation levels and dynamic int8 quantisation of one encoder."""
    from onnxruntime.quantization import QuantType, quantize_dynamic
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from export import onnx_export as ox

    ref = ox.make_session(onnx_bytes, 2, "all").run(None, {"crops": crops})[0]
    rows: list[tuple[str, ...]] = []
    for level in ("disable", "basic", "extended", "all"):
        cells = []
        for threads in (1, 2):
            s = ox.make_session(onnx_bytes, threads, level)
            cells.append(f"{time_ms(lambda s=s: s.run(None, {'crops': crops}), reps):.2f}")
        out = ox.make_session(onnx_bytes, 2, level).run(None, {"crops": crops})[0]
        cells.append(f"{_max_cos_change(ref, out):.1e}")
        rows.append((f"fp32, graph opt {level}", *cells))
    with tempfile.TemporaryDirectory(prefix="chpf-bench-q-") as tmp:
        raw = Path(tmp) / "raw.onnx"
        raw.write_bytes(onnx_bytes)
        src = Path(tmp) / "enc.onnx"
        quant_pre_process(raw, src)  # shape inference + optimisation, as onnxruntime advises
        for label, ops in (
            ("int8 dynamic, all ops", None),
            ("int8 dynamic, FC only", ["MatMul", "Gemm"]),
        ):
            dst = Path(tmp) / f"q{len(rows)}.onnx"
            kwargs = {} if ops is None else {"op_types_to_quantize": ops}
            try:
                quantize_dynamic(src, dst, weight_type=QuantType.QInt8, **kwargs)
                q = dst.read_bytes()
                cells = []
                for threads in (1, 2):
                    s = ox.make_session(q, threads, "all")
                    cells.append(f"{time_ms(lambda s=s: s.run(None, {'crops': crops}), reps):.2f}")
                out = ox.make_session(q, 2, "all").run(None, {"crops": crops})[0]
                cells.append(f"{_max_cos_change(ref, out):.1e}")
            except Exception as err:  # report, don't abort the benchmark
                cells = ["n/a", "n/a", type(err).__name__]
            rows.append((label, *cells))
    return rows


def _max_cos_change(ref: np.ndarray, out: np.ndarray) -> float:
    """max over rows of 1 - cos(ref_i, out_i)."""
    a = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    b = out / np.linalg.norm(out, axis=1, keepdims=True)
    return float(np.max(1.0 - np.sum(a * b, axis=1)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m export.bench", description=__doc__.split("\n")[0])
    p.add_argument("--object", default="mug", help="built-in object rendered for the crops")
    p.add_argument("--batch", type=int, default=50, help="crops per batch (default 50)")
    p.add_argument("--reps", type=int, default=10, help="timed runs per cell (best is shown)")
    p.add_argument("--codebook-entries", type=int, default=1000, help="entries rendered cold")
    p.add_argument("--skip-codebook", action="store_true", help="skip the codebook build timing")
    p.add_argument("--skip-poserbpf", action="store_true", help="skip the PoseRBPF-size encoder")
    p.add_argument("--ae", help="trained AE checkpoint for the default row (else random init)")
    p.add_argument(
        "--config",
        default=str(Path(__file__).resolve().parent.parent / "configs" / "train_ae.yaml"),
        help="training config whose model.encoder is the default row",
    )
    args = p.parse_args(argv)
    logging.getLogger().setLevel(logging.ERROR)  # onnxruntime.quantization's advice on stderr
    load0 = os.getloadavg()

    from export import onnx_export as ox

    configs = [("default", default_encoder(args.config))]
    trained = None
    if args.ae:
        from training.checkpoints import load_autoencoder

        ae, _ = load_autoencoder(args.ae)
        trained = ae.encoder
        configs = [("default (trained)", ae.encoder.config)]
    if not args.skip_poserbpf:
        configs.append(("PoseRBPF-size", POSERBPF_ENCODER))

    results = []
    with tempfile.TemporaryDirectory(prefix="chpf-bench-crops-") as cache:
        for i, (name, cfg) in enumerate(configs):
            crops = _crops(args.object, cfg.size, args.batch, Path(cache))
            reps = args.reps if cfg.size <= 64 else max(3, args.reps // 3)
            r = bench_encoder(name, cfg, crops, reps, trained if i == 0 else None)
            r["cfg"] = cfg
            r["crops"] = crops
            if not args.skip_codebook:
                sess = ox.make_session(r["onnx"], 2)
                r["render_s"], r["embed_s"] = _codebook_seconds_per_1000(
                    args.object,
                    cfg.size,
                    args.codebook_entries,
                    lambda c, s=sess: s.run(None, {"crops": c})[0],
                )
            results.append(r)

    n = args.batch
    big = max(3, args.reps // 3)
    load = ", ".join(f"{x:.1f}" for x in load0)
    print(f"\nload average at start: {load} (2 cores); times: best of {args.reps} runs")
    print(f"({big} at S > 64), warm-up excluded; torch eager with 2 threads")
    print(f"\nEncoders, batch of {n} crops of '{args.object}' (ms)")
    cols = ["S", "channels", "k", "E", "torch", "ort 1t", "ort 2t", "ms/crop 2t", "|ort-torch|"]
    widths = [18, 4, 18, 2, 4, 8, 8, 8, 10, 11]
    print(_row("encoder", cols, widths))
    for r in results:
        c = r["cfg"]
        cells = [
            str(c.size),
            "-".join(map(str, c.channels)),
            str(c.kernel),
            str(c.embedding_dim),
            f"{r['torch']:.2f}",
            f"{r['ort1']:.2f}",
            f"{r['ort2']:.2f}",
            f"{r['ort2'] / n:.3f}",
            f"{r['parity']:.1e}",
        ]
        print(_row(r["name"], cells, widths))

    print(f"\nCH head (hidden 256-128), {n} pairs (ms)")
    widths = [18, 8, 8, 8]
    print(_row("head for", ["torch", "ort 1t", "ort 2t"], widths))
    for r in results:
        cells = [f"{r['head_torch']:.3f}", f"{r['head_ort1']:.3f}", f"{r['head_ort2']:.3f}"]
        print(_row(r["name"], cells, widths))

    if not args.skip_codebook:
        print(
            f"\nCodebook build per 1,000 entries (cold pool of {args.codebook_entries}; "
            "embed: ort 2 threads)"
        )
        widths = [18, 9, 9, 9]
        print(_row("encoder", ["render s", "embed s", "total s"], widths))
        for r in results:
            cells = [
                f"{r['render_s']:.2f}",
                f"{r['embed_s']:.2f}",
                f"{r['render_s'] + r['embed_s']:.2f}",
            ]
            print(_row(r["name"], cells, widths))

    r0 = results[0]
    print(f"\nVariants of the {r0['name']} encoder, batch {n} (ms)")
    widths = [26, 8, 8, 13]
    print(_row("variant", ["1 thread", "2 threads", "max 1-cos"], widths))
    for row in bench_variants(r0["onnx"], r0["crops"], args.reps):
        print(_row(row[0], list(row[1:]), widths))
    return 0


cli = run_main(main)

if __name__ == "__main__":
    cli()
