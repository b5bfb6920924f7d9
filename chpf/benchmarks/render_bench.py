"""Benchmark of rendering and cropping.

`python -m chpf.benchmarks.render_bench` prints, for each built-in object (with its triangle
count): codebook crops per second (``render_crops``, a batch of 200 at 64x64: anti-aliased
colour, single-pass aliased colour, depth and mask only) and 640x480 full frames per second
(``Renderer.render``, one object); then the time of ``extract_crops`` for 50 crops of 64x64
from a 640x480 RGB image.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from chpf.crops import CropSpec, crop_affines, extract_crops, render_crops
from chpf.geometry import random_rotations
from chpf.objects import BUILTIN_OBJECTS, builtin_object
from chpf.render import Renderer

FRAME_K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])


def _rate(fn, count: int) -> float:
    """Items per second of ``fn()`` which handles ``count`` items (one warm-up call first)."""
    start = time.perf_counter()
    fn()
    return count / (time.perf_counter() - start)


def run(
    batch: int = 200,
    size: int = 64,
    frames: int = 20,
    n_crops: int = 50,
    objects: list[str] | None = None,
    seed: int = 0,
) -> dict:
    """Measure; returns {"objects": [row dict per object], "extract_ms": float, "setup": dict}."""
    rng = np.random.default_rng(seed)
    rows = []
    with Renderer(640, 480) as frame_renderer, Renderer(size, size) as crop_renderer:
        for name in objects or list(BUILTIN_OBJECTS):
            obj = builtin_object(name)
            spec = CropSpec.for_object(obj.diameter, size=size)
            Rs = random_rotations(batch, rng)
            render_crops(crop_renderer, obj, Rs[:3], spec)  # upload + shader compile
            row = {"object": name, "triangles": obj.num_triangles}

            def crops(obj=obj, Rs=Rs, spec=spec, **kw) -> None:
                render_crops(crop_renderer, obj, Rs, spec, **kw)

            row["crops_aa"] = _rate(crops, batch)
            row["crops_fast"] = _rate(lambda crops=crops: crops(antialias=False), batch)
            row["crops_depth"] = _rate(lambda crops=crops: crops(rgb=False), batch)
            t = np.array([0.03, -0.02, 3.0 * obj.diameter])
            Rf = random_rotations(frames, rng)
            frame_renderer.render([(obj, Rf[0], t)], FRAME_K)

            def frames_loop(antialias: bool, Rf=Rf, t=t, obj=obj) -> None:
                for R in Rf:
                    frame_renderer.render([(obj, R, t)], FRAME_K, antialias=antialias)

            row["frames_aa"] = _rate(lambda f=frames_loop: f(True), frames)
            row["frames_fast"] = _rate(lambda f=frames_loop: f(False), frames)
            rows.append(row)
    image = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    t = rng.uniform([-0.1, -0.1, 0.5], [0.1, 0.1, 1.0], (n_crops, 3))
    A = crop_affines(t, FRAME_K, CropSpec.for_object(0.2, size=size))
    extract_crops(image, A, size)
    times = []
    for _ in range(20):
        start = time.perf_counter()
        extract_crops(image, A, size)
        times.append(time.perf_counter() - start)
    setup = {"batch": batch, "size": size, "frames": frames, "n_crops": n_crops}
    return {"objects": rows, "extract_ms": float(np.median(times) * 1e3), "setup": setup}


def format_table(result: dict) -> str:
    """Plain-text table of run()'s result."""
    s = result["setup"]
    head = (
        f"{'object':<7} {'tris':>5} | {'crops/s':>8} {'crops/s':>8} {'crops/s':>8} | "
        f"{'frames/s':>8} {'frames/s':>8}"
    )
    sub = f"{'':<7} {'':>5} | {'AA':>8} {'no AA':>8} {'depth':>8} | {'AA':>8} {'no AA':>8}"
    lines = [
        f"render_crops: batches of {s['batch']} at {s['size']}x{s['size']}; "
        f"frames: 640x480, one object, {s['frames']} poses",
        head,
        sub,
        "-" * len(head),
    ]
    for r in result["objects"]:
        lines.append(
            f"{r['object']:<7} {r['triangles']:>5} | {r['crops_aa']:>8.0f} {r['crops_fast']:>8.0f} "
            f"{r['crops_depth']:>8.0f} | {r['frames_aa']:>8.1f} {r['frames_fast']:>8.1f}"
        )
    lines.append(
        f"extract_crops: {s['n_crops']} crops of {s['size']}x{s['size']} from 640x480 RGB: "
        f"{result['extract_ms']:.2f} ms (median of 20)"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark table; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=200, help="crops per render_crops batch")
    parser.add_argument("--size", type=int, default=64, help="crop size S (pixels)")
    parser.add_argument("--frames", type=int, default=20, help="640x480 frames per object")
    parser.add_argument("--objects", nargs="*", choices=list(BUILTIN_OBJECTS), default=None)
    args = parser.parse_args(argv)
    result = run(batch=args.batch, size=args.size, frames=args.frames, objects=args.objects)
    print(format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
