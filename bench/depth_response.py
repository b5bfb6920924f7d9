"""How a bundle's networks answer a wrong depth: L and C at the true pose moved along its ray.

``python -m bench.depth_response --suite dev`` builds (or reads from ``--cache-dir``) the
suite's sequences and, on every ``--every``-th frame of each, scores the true orientation at
the true translation times each factor of ``--factors`` (a factor f puts the object f times as
far along the same ray: the crop is cut as for a hypothesis that much too far, or too near) with
the bundle's likelihood (the autoencoder's L = max(cos, 0) and the classifier's C, without the
detection box's terms). It prints, per band of visible fraction (scene_gt_info), the mean L and
C per factor and how often each factor has the highest L; ``--figure PNG`` draws both curves.

A likelihood that constrains depth peaks at f = 1 and falls off on both sides; a classifier
that sees depth errors rises there. With the shipped box bundle C stayed near 0 from f = 0.8
to 1.25 on unoccluded frames (docs/chpf-ablations.md): the classifier judged orientation only,
so CH-PF's doubt could not see a set that had drifted in depth.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.likelihoods import BANDS, band_index
from bench.sequences import build_sequences, default_cache_dir, resolve_bundles
from bench.suite import load_suite

FACTORS = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2, 1.25)


def responses(likelihood, scene, obj_id: int, factors: np.ndarray, every: int):
    """(band index, L (F,), C (F,)) for every ``every``-th frame of a BopScene showing
    ``obj_id``: the true pose with its translation times each factor (F,)."""
    from chpf.tracking.types import Frame

    for im in scene.image_ids()[::every]:
        found = [(i, g) for i, g in enumerate(scene.gt.get(im, [])) if g.obj_id == obj_id]
        if not found:
            continue
        i, gt = found[0]
        frame = Frame(rgb=scene.rgb(im), depth=None, K=scene.camera(im).K)
        t = np.asarray(gt.t, dtype=np.float64)[None] * factors[:, None]
        R = np.broadcast_to(np.asarray(gt.R, dtype=np.float64), (len(factors), 3, 3))
        scores = likelihood.score(frame, R, t)
        yield band_index(scene.gt_info[im][i].visib_fract), scores.L, scores.C


def band_name(b: int) -> str:
    """Band ``b`` of BANDS as "lo-hi"."""
    return f"{BANDS[b][0]:.1f}-{BANDS[b][1]:.1f}"


def table(rows: dict[int, list], factors: np.ndarray) -> str:
    """The printed table: per band, mean L, mean C and argmax-L counts per factor."""
    head = "| band | n | | " + " | ".join(f"{f:g}" for f in factors) + " |"
    lines = [head, "|" + " --- |" * (len(factors) + 3)]
    for b, got in sorted(rows.items()):
        L = np.array([g[0] for g in got])
        C = np.array([g[1] for g in got])
        name = band_name(b)
        best = np.bincount(L.argmax(axis=1), minlength=len(factors))
        for what, vals in (("L", L.mean(0)), ("C", C.mean(0))):
            lines.append(
                f"| {name} | {len(got)} | {what} | " + " | ".join(f"{v:.3f}" for v in vals) + " |"
            )
        lines.append(f"| {name} | {len(got)} | best L | " + " | ".join(str(v) for v in best) + " |")
    return "\n".join(lines)


def draw(rows: dict[int, list], factors: np.ndarray, path: Path, title: str) -> None:
    """L and C against the depth factor, one line per band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharex=True)
    for b, got in sorted(rows.items()):
        label = f"{band_name(b)} visible ({len(got)})"
        for ax, k in zip(axes, (0, 1), strict=True):
            ax.plot(factors, np.mean([g[k] for g in got], axis=0), marker="o", label=label)
    for ax, name in zip(axes, ("L (autoencoder)", "C (classifier)"), strict=True):
        ax.set_xlabel("depth / true depth")
        ax.set_ylabel(name)
        ax.axvline(1.0, color="grey", lw=0.8)
        ax.set_ylim(0, 1)
    axes[1].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.depth_response", description=__doc__)
    p.add_argument("--suite", default="dev", help="a suite name or YAML (its sequences)")
    p.add_argument("--bundle", default=None, help="bundle folder (default: the suite's)")
    p.add_argument("--cache-dir", type=Path, default=None, help="sequence cache folder")
    p.add_argument("--every", type=int, default=2, help="score every n-th frame")
    p.add_argument("--factors", default=",".join(f"{f:g}" for f in FACTORS))
    p.add_argument("--figure", type=Path, default=None, help="PNG of both curves")
    args = p.parse_args(argv)
    from chpf.bop import BopDataset
    from chpf.bundle import Bundle
    from chpf.tracking.bundle_likelihood import BundleLikelihood

    factors = np.array([float(f) for f in args.factors.split(",")])
    suite = load_suite(args.suite, {"modalities": ["rgb"]})
    seqs = build_sequences(suite, resolve_bundles(suite), args.cache_dir or default_cache_dir())
    path = args.bundle or seqs[0].bundle
    likelihood = BundleLikelihood(Bundle.load(path, spin=False), c_mode="learned")
    rows: dict[int, list] = {}
    for seq in seqs:
        scene = BopDataset(seq.root).scene("test", seq.scene_id)
        for b, L, C in responses(likelihood, scene, seq.obj_id, factors, max(args.every, 1)):
            rows.setdefault(b, []).append((L, C))
    print(f"bundle {path}, suite {suite.name}: L and C at the true pose, depth times f")
    print(table(rows, factors))
    if args.figure is not None:
        draw(rows, factors, args.figure, f"{Path(path).name} on {suite.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
