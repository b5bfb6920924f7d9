"""Held-out evaluation of the trained likelihood networks (prints the issue's figures).

::

    python -m training.evaluate --ae runs/ae/checkpoints/best.ckpt --data data/mug_ae_test \\
        --codebook-k 20000 [--ch runs/ch/checkpoints/best.ckpt --pairs data/mug_pairs_test] \\
        [--codebook val_codebook.npz] [--max-samples 4000] [--json eval.json]

Use shard folders generated with another ``--seed`` than the training data (new orientations,
augmented and occluded as in training).

Autoencoder: nearest-by-cosine retrieval of the augmented held-out crops against a uniform-grid
codebook (>= 20k entries for the issue's figure), symmetry-aware error in degrees: median and %
under 30 degrees (clean target crops too, for reference).
Classifier (``--ch`` + ``--pairs``): ROC AUC on all pairs that show the object (every kind of
negative the folder holds: for the issue's "random negatives" figure, generate the folder with
``--set pairs.hard_negative_share=0 --set pairs.flip_negative_share=0``) and on hard negatives
(20-45 degrees), the share of positives called aligned (p < 0.5), overall and for
objects 30-60% visible, and the autoencoder's cosine between the observed and the candidate crop
on the same pairs (its AUC, and how far it drops from well-visible to 30-60%-visible positives).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from chpf.atomic import atomic_write_text
from chpf.console import run_main
from chpf.errors import ConfigError
from chpf.objects import MESH_UNITS
from data_gen.compose import depth_off, scale_error
from data_gen.config import data_pairs_config
from training.checkpoints import load_autoencoder, load_classifier
from training.data import open_shards, shard_crop_size
from training.lit import classifier_metrics, load_codebook_npz, pair_subsets
from training.metrics import (
    band_label,
    cosine_retrieval,
    retrieval_summary,
    roc_auc,
    roc_auc_interval,
    symmetry_aware_angle,
)
from training.models import Preprocess


def load_samples(
    data_dir: str | os.PathLike, kind: str, keys: list[str], max_samples: int, seed: int
) -> dict[str, np.ndarray]:
    """Up to ``max_samples`` samples (seeded subset, in shard order) of a shard folder."""
    reader = open_shards(data_dir, kind)
    sizes = [int(s["n"]) for s in reader.manifest["shards"]]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    total = int(offsets[-1])
    idx = np.arange(total)
    if 0 < max_samples < total:
        idx = np.sort(np.random.default_rng(seed).choice(total, max_samples, replace=False))
    parts: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    for s in range(len(sizes)):
        local = idx[(idx >= offsets[s]) & (idx < offsets[s + 1])] - offsets[s]
        if local.size == 0:
            continue
        arrays = reader.load_shard(s)
        for k in keys:
            parts[k].append(np.asarray(arrays[k])[local])
    return {k: np.concatenate(v) for k, v in parts.items()}


@torch.no_grad()
def embed(encoder: torch.nn.Module, crops: np.ndarray, batch: int = 256) -> np.ndarray:
    """L2-normalised embeddings ``(N, E)`` of uint8 crops ``(N, S, S, 3)`` with ``encoder``."""
    pre = Preprocess()
    out = []
    for i in range(0, crops.shape[0], batch):
        x = pre(torch.from_numpy(np.ascontiguousarray(crops[i : i + batch])))
        out.append(F.normalize(encoder(x), dim=1))
    return torch.cat(out).numpy()


@torch.no_grad()
def classifier_logits(model: torch.nn.Module, obs: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Logits of P(misaligned) ``(N,)`` of a CHClassifier for uint8 crop pairs."""
    e_obs = torch.from_numpy(embed(model.obs_encoder, obs))
    e_cand = torch.from_numpy(embed(model.cand_encoder, cand))
    return model.head(e_obs, e_cand).numpy()


def evaluate_ae(
    ae_path: str,
    data_dir: str,
    codebook: dict[str, np.ndarray],
    max_samples: int,
    seed: int,
) -> dict[str, Any]:
    """Retrieval figures of an autoencoder checkpoint on a held-out ae shard folder."""
    ae, _ = load_autoencoder(ae_path)
    size = ae.config.size
    reader = open_shards(data_dir, "ae")
    if shard_crop_size(reader) != size:
        raise ConfigError(
            f"{Path(data_dir) / 'manifest.json'}: crop size {shard_crop_size(reader)} differs "
            f"from the autoencoder's {size} ({ae_path})"
        )
    if codebook["crops"].shape[1] != size:
        raise ConfigError(f"codebook crop size {codebook['crops'].shape[1]} != model size {size}")
    t0 = time.perf_counter()
    cb_emb = embed(ae.encoder, codebook["crops"])
    t_cb = time.perf_counter() - t0
    keys = ["input_rgb", "target_rgb", "R_allo", "visib_fract"]
    data = load_samples(data_dir, "ae", keys, max_samples, seed)
    shows_object = data["visib_fract"] > 0  # retrieval is undefined for empty crops
    data = {k: v[shows_object] for k, v in data.items()}
    sym_d = list(codebook["symmetries_discrete"])
    sym_c = [{"axis": a} for a in codebook["symmetries_continuous_axes"]]
    cb_R = codebook["rotations"].astype(np.float64)
    out: dict[str, Any] = {
        "codebook_size": int(cb_R.shape[0]),
        "n_samples": int(data["R_allo"].shape[0]),
        "n_empty_skipped": int((~shows_object).sum()),
        "codebook_embed_s": round(t_cb, 2),
    }
    for key, label in (("input_rgb", "augmented"), ("target_rgb", "clean")):
        idx, _ = cosine_retrieval(embed(ae.encoder, data[key]), cb_emb)
        err = np.degrees(symmetry_aware_angle(cb_R[idx], data["R_allo"], sym_d, sym_c))
        out[label] = retrieval_summary(err, 30.0)
        if label == "augmented":
            out["augmented_by_visibility"] = by_visibility(err, data["visib_fract"])
    return out


VISIBILITY_BANDS = ((0.9, 1.0), (0.6, 0.9), (0.3, 0.6), (0.0, 0.3))


def visibility_band(visib: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Mask (N,) of visible fractions ``visib`` (N,) in [lo, hi), closed at hi = 1."""
    return (visib >= lo) & ((visib < hi) | (hi >= 1.0))


def by_visibility(err_deg: np.ndarray, visib: np.ndarray) -> list[dict[str, Any]]:
    """Retrieval summaries of the errors ``err_deg`` (N,) degrees per band of the visible
    fraction ``visib`` (N,): bands [lo, hi), the top one closed, empty crops (visib 0) in none;
    with the crop count and the share (%) turned more than 150 degrees (front/back look-alikes)."""
    rows = []
    for lo, hi in VISIBILITY_BANDS:
        m = visibility_band(visib, lo, hi) & (visib > 0)
        above150 = float(100.0 * np.mean(err_deg[m] > 150)) if m.any() else float("nan")
        rows.append(
            {
                "visib": [lo, hi],
                "n": int(m.sum()),
                **retrieval_summary(err_deg[m], 30.0),
                "pct_above150": above150,
            }
        )
    return rows


def hard_auc_in_bands(
    logit: np.ndarray, pos: np.ndarray, hard: np.ndarray, bands: list[np.ndarray]
) -> list[dict[str, Any]]:
    """ROC AUC of the misalignment ``logit`` (N,) on the positives against the hard negatives
    (boolean masks, N) of each band (a boolean mask, N), with their counts; NaN where a band
    lacks either."""
    rows = []
    for band in bands:
        p, h = pos & band, hard & band
        sel = p | h
        auc = roc_auc(logit[sel], h[sel].astype(np.int64)) if p.any() and h.any() else float("nan")
        rows.append({"n_pos": int(p.sum()), "n_hard": int(h.sum()), "auc": auc})
    return rows


def hard_auc_by_visibility(
    logit: np.ndarray, pos: np.ndarray, hard: np.ndarray, visib: np.ndarray
) -> list[dict[str, Any]]:
    """``hard_auc_in_bands`` over the bands of ``VISIBILITY_BANDS`` but the lowest (a pair
    counts in the band of its own ``visib``, ``visibility_band``)."""
    edges = VISIBILITY_BANDS[:-1]
    rows = hard_auc_in_bands(logit, pos, hard, [visibility_band(visib, *e) for e in edges])
    return [{"visib": list(e), **r} for e, r in zip(edges, rows, strict=True)]


# bands [lo, hi) of a crop's scale error |ln(z_crop / z)|, the last one open (hi None); the
# crop jitter's z_sigma is 0.05
SCALE_OFF_BANDS = ((0.0, 0.02), (0.02, 0.05), (0.05, 0.08), (0.08, None))


def hard_auc_by_scale_off(
    logit: np.ndarray, pos: np.ndarray, hard: np.ndarray, depth_ratio: np.ndarray
) -> list[dict[str, Any]]:
    """``hard_auc_in_bands`` over the bands of ``SCALE_OFF_BANDS`` of the crops' scale error
    |ln depth_ratio| (``depth_ratio`` (N,): the depth each crop was cut at over the true one):
    how far the crop jitter's scale holds the classifier back."""
    off = scale_error(depth_ratio)
    masks = [(off >= lo) & (off < (np.inf if hi is None else hi)) for lo, hi in SCALE_OFF_BANDS]
    rows = hard_auc_in_bands(logit, pos, hard, masks)
    return [{"scale_off": [lo, hi], **r} for (lo, hi), r in zip(SCALE_OFF_BANDS, rows, strict=True)]


FAR_DEG = (45.0, 150.0)  # negatives drawn at random: past the hard ones, short of the flips


def far_negatives(y: np.ndarray, angle_deg: np.ndarray, visib: np.ndarray) -> np.ndarray:
    """Mask (N,) of the negatives (``y`` 1) that show the object and are ``FAR_DEG`` degrees
    off: in a test folder with the data's mix, the random ones without the flips (about 180)
    and the hard ones (20-45): the report card's random-negatives figure."""
    return pair_subsets(y, angle_deg, visib, FAR_DEG)[1]  # its "hard" mask, at FAR_DEG


def evaluate_pairs(
    pairs_dir: str,
    ae_path: str | None,
    ch_path: str | None,
    max_samples: int,
    seed: int,
    hard_deg: tuple[float, float] = (20.0, 45.0),
    occluded_visib: tuple[float, float] = (0.3, 0.6),
    clear_visib: float = 0.9,
) -> dict[str, Any]:
    """Classifier figures and the autoencoder cosine on a held-out pairs shard folder."""
    keys = ["obs_rgb", "cand_rgb", "aligned", "angle_deg", "visib_fract", "depth_ratio"]
    data = load_samples(pairs_dir, "pairs", keys, max_samples, seed)
    y = 1 - data["aligned"].astype(np.int64)  # 1 = misaligned
    visib = data["visib_fract"]
    pos, hard, occl, empty = pair_subsets(y, data["angle_deg"], visib, hard_deg, occluded_visib)
    pairs_cfg = data_pairs_config(open_shards(pairs_dir, "pairs").manifest)
    off = (y == 1) & ~empty & depth_off(data["depth_ratio"], pairs_cfg)  # scale negatives
    clear = pos & (visib >= clear_visib)
    out: dict[str, Any] = {
        "n_pairs": int(y.size),
        "n_positives": int(pos.sum()),
        "n_hard_negatives": int(hard.sum()),
        "n_occluded_positives": int(occl.sum()),
        "n_empty_negatives": int(empty.sum()),
        "n_depth_negatives": int(off.sum()),
    }

    far = far_negatives(y, data["angle_deg"], visib)

    def auc_against(score: np.ndarray, neg: np.ndarray) -> float:  # positives against neg
        sel = pos | neg
        return roc_auc(score[sel], y[sel]) if neg.any() and pos.any() else float("nan")

    if ch_path:
        ch, info = load_classifier(ch_path)
        logit = classifier_logits(ch, data["obs_rgb"], data["cand_rgb"])
        m = classifier_metrics(logit, y, data["angle_deg"], visib, hard_deg, occluded_visib)
        hard_lo, hard_hi = roc_auc_interval(logit[pos | hard], y[pos | hard], seed=seed)
        out["classifier"] = {
            "shares_ae_encoder": bool(info.get("shares_ae_encoder", False)),
            **{k: m[k] for k in ("acc", "auc", "auc_hard", "aligned_rate_pos", "empty_rejected")},
            "aligned_rate_occluded": m["aligned_rate_occluded"],
            "auc_hard_lo": hard_lo,  # its 95 % bootstrap interval
            "auc_hard_hi": hard_hi,
            "auc_far": auc_against(logit, far),
            "auc_hard_by_visibility": hard_auc_by_visibility(logit, pos, hard, visib),
            "auc_hard_by_scale_off": hard_auc_by_scale_off(logit, pos, hard, data["depth_ratio"]),
            "auc_depth": auc_against(logit, off),
        }
    if ae_path:
        ae, _ = load_autoencoder(ae_path)
        cos = np.sum(embed(ae.encoder, data["obs_rgb"]) * embed(ae.encoder, data["cand_rgb"]), 1)

        def _mean(mask: np.ndarray) -> float:
            return float(cos[mask].mean()) if mask.any() else float("nan")

        out["ae_cosine"] = {
            "auc": roc_auc(-cos[~empty], y[~empty]),
            "auc_hard": auc_against(-cos, hard),
            "auc_depth": auc_against(-cos, off),
            "mean_pos_clear": _mean(clear),
            "mean_pos_occluded": _mean(occl),
            "mean_neg": _mean(y == 1),
            "mean_hard_neg": _mean(hard),
            "mean_empty": _mean(empty),
            "drop_occluded": _mean(clear) - _mean(occl),
        }
    return out


def format_report(res: dict[str, Any]) -> str:
    """Human-readable table of the figures."""
    lines = []
    if "ae" in res:
        a = res["ae"]
        lines.append(
            f"autoencoder retrieval vs {a['codebook_size']}-entry codebook, "
            f"{a['n_samples']} held-out crops ({a['n_empty_skipped']} empty crops skipped):"
        )
        for label in ("augmented", "clean"):
            s = a[label]
            lines.append(
                f"  {label:9s}  median {s['median_deg']:6.2f} deg   mean {s['mean_deg']:6.2f} deg"
                f"   < 30 deg {s['pct_below']:5.1f} %"
            )
        for b in a["augmented_by_visibility"]:
            lines.append(
                f"    {b['visib'][0]:.1f}-{b['visib'][1]:.1f} visible ({b['n']:4d} crops): median "
                f"{b['median_deg']:6.2f} deg   < 30 deg {b['pct_below']:5.1f} %   > 150 deg "
                f"{b['pct_above150']:5.1f} %"
            )
    if "pairs" in res:
        p = res["pairs"]
        lines.append(
            f"pairs: {p['n_pairs']} ({p['n_positives']} positives, {p['n_hard_negatives']} hard "
            f"negatives 20-45 deg, {p['n_occluded_positives']} positives 30-60% visible, "
            f"{p['n_empty_negatives']} empty-crop negatives; AUCs over pairs with the object)"
        )
        if "classifier" in p:
            c = p["classifier"]
            lo, hi = c["auc_hard_lo"], c["auc_hard_hi"]
            lines.append(
                f"  classifier ROC AUC {c['auc']:.4f} (all negatives), {c['auc_hard']:.4f} "
                f"(hard; 95 % interval {lo:.3f}-{hi:.3f}), {c['auc_far']:.4f} "
                f"({FAR_DEG[0]:g}-{FAR_DEG[1]:g} deg off), "
                f"acc {c['acc']:.4f}, shares AE encoder: {c['shares_ae_encoder']}"
            )
            lines.append(
                f"  positives called aligned: {100 * c['aligned_rate_pos']:.1f} % overall, "
                f"{100 * c['aligned_rate_occluded']:.1f} % of those 30-60% visible; empty crops "
                f"called misaligned: {100 * c['empty_rejected']:.1f} %"
            )
            bands = [
                f"{b['visib'][0]:.1f}-{b['visib'][1]:.1f} visible {b['auc']:.4f} "
                f"({b['n_pos']} pos / {b['n_hard']} hard)"
                for b in c["auc_hard_by_visibility"]
            ]
            lines.append("  hard-negative AUC by visibility: " + ", ".join(bands))
            scales = [
                f"{band_label(*b['scale_off'])} {b['auc']:.4f} "
                f"({b['n_pos']} pos / {b['n_hard']} hard)"
                for b in c["auc_hard_by_scale_off"]
            ]
            lines.append(
                "  hard-negative AUC by the crop's scale error |ln z'/z|: " + ", ".join(scales)
            )
            if p["n_depth_negatives"]:
                lines.append(
                    f"  ROC AUC against the {p['n_depth_negatives']} scale negatives (right "
                    f"orientation, wrong depth): {c['auc_depth']:.4f}"
                )
        if "ae_cosine" in p:
            e = p["ae_cosine"]
            lines.append(
                f"  AE cosine ROC AUC {e['auc']:.4f} (all), {e['auc_hard']:.4f} (hard); mean "
                f"cosine on positives: {e['mean_pos_clear']:.3f} (>= 90% visible) -> "
                f"{e['mean_pos_occluded']:.3f} (30-60% visible), drop {e['drop_occluded']:.3f}; "
                f"negatives {e['mean_neg']:.3f}, hard negatives {e['mean_hard_neg']:.3f}, "
                f"empty crops {e['mean_empty']:.3f}"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m training.evaluate",
        description="Held-out figures of the autoencoder and the CH classifier.",
    )
    p.add_argument("--ae", help="autoencoder checkpoint")
    p.add_argument("--ch", help="CH classifier checkpoint")
    p.add_argument("--data", help="held-out ae shard folder (autoencoder retrieval)")
    p.add_argument("--pairs", help="held-out pairs shard folder (classifier, AE cosine)")
    p.add_argument("--codebook", help="codebook npz from python -m training.codebook")
    p.add_argument("--codebook-k", type=int, default=20000, help="grid size if no --codebook")
    p.add_argument("--object", default=None, help="object override for building the codebook")
    p.add_argument(
        "--unit", default=None, choices=list(MESH_UNITS), help="--object's unit (default m)"
    )
    p.add_argument("--cache-dir", default=None, help="data_gen pool cache folder")
    p.add_argument("--workers", type=int, default=1, help="render workers for the codebook")
    p.add_argument("--max-samples", type=int, default=4000, help="held-out samples (0 = all)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--json", help="also write the figures as JSON here")
    a = p.parse_args(argv)
    if not a.ae and not a.ch:
        raise ConfigError("give --ae and/or --ch")
    if a.data and not a.ae:
        raise ConfigError("--data (autoencoder retrieval) needs --ae")
    if a.ch and not a.pairs:
        raise ConfigError("--ch needs --pairs (a held-out pairs folder)")
    torch.set_num_threads(max(1, a.threads))
    res: dict[str, Any] = {}
    t0 = time.perf_counter()
    if a.data:
        if a.codebook:
            cb = load_codebook_npz(a.codebook)
            cb.setdefault("symmetries_discrete", np.zeros((0, 4, 4)))
            cb.setdefault("symmetries_continuous_axes", np.zeros((0, 3)))
        else:
            from training.codebook import render_eval_codebook

            cb = render_eval_codebook(
                a.data, a.codebook_k, a.object, a.unit, a.cache_dir, a.workers
            )
        res["ae"] = evaluate_ae(a.ae, a.data, cb, a.max_samples, a.seed)
    if a.pairs:
        res["pairs"] = evaluate_pairs(a.pairs, a.ae, a.ch, a.max_samples, a.seed)
    res["wall_s"] = round(time.perf_counter() - t0, 1)
    print(format_report(res))
    print(f"wall time {res['wall_s']} s")
    if a.json:
        atomic_write_text(a.json, json.dumps(res, indent=1) + "\n")
    return 0


cli = run_main(main)

if __name__ == "__main__":
    cli()
