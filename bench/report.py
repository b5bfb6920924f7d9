"""The report of a bench folder: ``OUT/report/`` with report.md, tables (CSV, JSON) and PNGs.

Tables: ADD-S and ADD AUC (0-10 cm) per method x modality x occlusion level (and all), over
all frames and over occluded frames (< 75 % visible), each the mean over seeds with a 95 %
bootstrap interval over sequences (bench.stats); per method x modality the share of frames
tracked (ADD-S < 0.1 diameter), the re-acquisition time after a loss and the fps. Figures:
AUC by occlusion level, accuracy-threshold curves, error and alpha over time on the most
occluded sequences, and frames with every method's outline at its estimate.
"""

from __future__ import annotations

import csv
import io
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from bench.runner import SUMMARY
from bench.sequences import SEQUENCES_FILE, sequences_from_json
from bench.stats import (
    HIDDEN_BELOW,
    LOST_ABOVE,
    OCCLUDED_BELOW,
    TRACKED_BELOW,
    Estimate,
    auc_stat,
    bootstrap,
    reacquisition,
    tracked_stat,
)
from chpf.atomic import atomic_write_bytes, atomic_write_text
from chpf.errors import DatasetError

SUITE_FILE = "suite.json"
TIMINGS_FILE = "timings.json"
FPS = 30.0  # frame rate of the sequences (data_gen.sequences.FPS)
METRICS = {"adds": "ADD-S", "add": "ADD"}
SUBSETS = ("all", "occluded")


def load_summaries(out: Path) -> list[dict[str, Any]]:
    """Every finished job's summary, its error lists as arrays (None -> inf, alpha nan)."""
    rows = []
    for p in sorted((Path(out) / "jobs").glob(f"*/{SUMMARY}")):
        s = json.loads(p.read_text(encoding="utf-8"))
        for k in ("add", "adds", "add_s"):
            s[k] = np.array([np.inf if v is None else v for v in s[k]], dtype=np.float64)
        for k in ("alpha", "ms"):
            s[k] = np.array([np.nan if v is None else v for v in s[k]], dtype=np.float64)
        s["visib"] = np.asarray(s["visib"], dtype=np.float64)
        s["dir"] = p.parent
        rows.append(s)
    return rows


def _counts(t: dict[str, Any]) -> list[Any]:
    return [t["losses"], t["unrecovered"], round(t["fps"], 2)]


def _rounded(e: Estimate) -> list[float]:
    return [round(v, 3) for v in (e.value, e.lo, e.hi)]


def _fmt(e: Estimate) -> str:
    if not np.isfinite(e.value):
        return "-"
    return f"{e.value:.1f} [{e.lo:.1f}, {e.hi:.1f}]"


class Figures:
    """The numbers of a report (see the module docstring)."""

    def __init__(self, suite: dict[str, Any], summaries: list[dict[str, Any]]) -> None:
        self.suite = suite
        self.methods = [m for m in suite["methods"] if any(s["method"] == m for s in summaries)]
        self.modalities = [
            m for m in suite["modalities"] if any(s["modality"] == m for s in summaries)
        ]
        self.levels = [*suite["sequences"]["occlusion"], "all"]
        self.by_cell: dict[tuple[str, str], dict[str, dict[int, dict]]] = defaultdict(
            lambda: defaultdict(dict)
        )
        for s in summaries:
            self.by_cell[(s["method"], s["modality"])][s["sequence"]][s["seed"]] = s
        self.seeds = suite["seeds"]
        self.resamples = suite["report"]["bootstrap"]

    def _per_seed(self, method: str, modality: str, level: str, subset: str, metric: str):
        seqs = self.by_cell[(method, modality)]
        keys = sorted(
            k
            for k, by_seed in seqs.items()
            if all(sd in by_seed for sd in self.seeds)
            and (level == "all" or by_seed[self.seeds[0]]["level"] == level)
        )
        per_seed = []
        for sd in self.seeds:
            items = []
            for k in keys:
                s = seqs[k][sd]
                sel = s["visib"] < OCCLUDED_BELOW if subset == "occluded" else slice(None)
                e = s[metric][sel]
                items.append((e, np.full(len(e), s["diameter"])))
            per_seed.append(items)
        return per_seed

    def auc(self, method: str, modality: str, level: str, subset: str, metric: str) -> Estimate:
        per_seed = self._per_seed(method, modality, level, subset, metric)
        return bootstrap(per_seed, auc_stat, self.resamples)

    def tracking(self, method: str, modality: str) -> dict[str, Any]:
        """tracked share (%) with interval, re-acquisition (s), losses, unrecovered, fps."""
        tracked = bootstrap(
            self._per_seed(method, modality, "all", "all", "adds"), tracked_stat, self.resamples
        )
        times, unrecovered, frames, ms = [], 0, 0, 0.0
        for by_seed in self.by_cell[(method, modality)].values():
            for s in by_seed.values():
                ok = s["adds"] < TRACKED_BELOW * s["diameter"]
                t, u = reacquisition(ok)
                times += t
                unrecovered += u
                good = np.isfinite(s["ms"])
                frames += int(good.sum())
                ms += float(s["ms"][good].sum())
        return {
            "tracked": tracked,
            "reacq_s": float(np.mean(times)) / FPS if times else float("nan"),
            "losses": len(times) + unrecovered,
            "unrecovered": unrecovered,
            "fps": 1000.0 * frames / ms if ms > 0 else float("nan"),
        }

    def alpha_by_state(self, method: str, modality: str) -> dict[str, tuple[float, ...]]:
        """Mean alpha per frame state (ALPHA_STATES): (mean over seeds of each seed's mean,
        lowest and highest seed mean, frames over all seeds); nan where none or no alpha."""
        per_seed: dict[str, list[float]] = defaultdict(list)
        frames: dict[str, int] = defaultdict(int)
        for sd in self.seeds:
            sums: dict[str, list[np.ndarray]] = defaultdict(list)
            for by_seed in self.by_cell[(method, modality)].values():
                s = by_seed.get(sd)
                if s is None:
                    continue
                for state, sel in frame_states(s).items():
                    a = s["alpha"][sel]
                    sums[state].append(a[np.isfinite(a)])
            for state in ALPHA_STATES:
                a = np.concatenate(sums[state]) if sums[state] else np.empty(0)
                frames[state] += a.size
                if a.size:
                    per_seed[state].append(float(a.mean()))
        nan = float("nan")
        return {
            k: (float(np.mean(v)), min(v), max(v), frames[k])
            if (v := per_seed[k])
            else (nan, nan, nan, 0)
            for k in ALPHA_STATES
        }


ALPHA_STATES = ("tracked", "lost", "occluded tracked", "hidden tracked")
"""Frame states of the alpha table: ADD-S < TRACKED_BELOW d; > LOST_ABOVE d; tracked with less
than OCCLUDED_BELOW of the target visible; tracked with less than HIDDEN_BELOW visible."""


def frame_states(s: dict[str, Any]) -> dict[str, np.ndarray]:
    """Boolean frame masks (n,) of a job summary for each of ALPHA_STATES."""
    tracked = s["adds"] < TRACKED_BELOW * s["diameter"]
    return {
        "tracked": tracked,
        "lost": s["adds"] > LOST_ABOVE * s["diameter"],
        "occluded tracked": tracked & (s["visib"] < OCCLUDED_BELOW),
        "hidden tracked": tracked & (s["visib"] < HIDDEN_BELOW),
    }


def alpha_table(fig: Figures, alpha: dict) -> str:
    """Markdown: mean alpha by frame state for the methods that report one."""
    head = ["method", "modality", *ALPHA_STATES]
    rows = []
    for (m, mod), by_state in alpha.items():
        cells = [
            f"{v:.2f} ({lo:.2f}-{hi:.2f}; {n})" if n else "-" for v, lo, hi, n in by_state.values()
        ]
        rows.append([m, mod, *cells])
    return md_table(head, rows)


def md_table(head: list[str], rows: list[list[str]]) -> str:
    """A markdown table of ``head`` and ``rows`` (cells already text)."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def headline_table(fig: Figures, auc: dict, track: dict) -> str:
    """Markdown: per method x modality, AUCs over all sequences (all and occluded frames)."""
    head = ["method", "modality", "ADD-S AUC", "ADD AUC", "ADD-S AUC occl.", "ADD AUC occl."]
    head += ["tracked %", "re-acq. s", "fps"]
    rows = []
    for mod in fig.modalities:
        for m in fig.methods:
            t = track[(m, mod)]
            cells = [_fmt(auc[(m, mod, "all", sub, k)]) for sub in SUBSETS for k in METRICS]
            cells = [cells[0], cells[1], cells[2], cells[3]]
            rows.append(
                [m, mod, *cells, _fmt(t["tracked"]), _num(t["reacq_s"], 2), _num(t["fps"], 1)]
            )
    return md_table(head, rows)


def _num(x: float, digits: int) -> str:
    return f"{x:.{digits}f}" if np.isfinite(x) else "-"


def level_table(fig: Figures, auc: dict) -> str:
    """Markdown: per method x modality x occlusion level, the four AUCs."""
    head = ["method", "modality", "occlusion", "ADD-S AUC", "ADD AUC"]
    head += ["ADD-S AUC occl.", "ADD AUC occl."]
    rows = []
    for mod in fig.modalities:
        for m in fig.methods:
            for lv in fig.levels[:-1]:
                cells = [_fmt(auc[(m, mod, lv, sub, k)]) for sub in SUBSETS for k in METRICS]
                rows.append([m, mod, lv, *cells])
    return md_table(head, rows)


def csv_text(rows: list[list[Any]], head: list[str]) -> str:
    """CSV text: the header ``head``, then ``rows``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    w.writerows(rows)
    return buf.getvalue()


def _png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_levels(fig: Figures, auc: dict) -> bytes:
    """ADD-S AUC by occlusion level, one bar per method with its interval, a panel per modality."""
    plt = _plt()
    f, axes = plt.subplots(1, len(fig.modalities), figsize=(5 * len(fig.modalities), 3.2))
    axes = np.atleast_1d(axes)
    width = 0.8 / max(len(fig.methods), 1)
    for ax, mod in zip(axes, fig.modalities, strict=True):
        x = np.arange(len(fig.levels))
        for i, m in enumerate(fig.methods):
            est = [auc[(m, mod, lv, "all", "adds")] for lv in fig.levels]
            v = np.array([e.value for e in est])
            err = np.array([[e.value - e.lo for e in est], [e.hi - e.value for e in est]])
            ax.bar(x + i * width - 0.4 + width / 2, v, width, yerr=err, label=m, capsize=2)
        ax.set_xticks(x, fig.levels)
        ax.set_ylim(0, 100)
        ax.set_title(f"ADD-S AUC, {mod}")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    f.tight_layout()
    return _png(f)


def plot_curves(fig: Figures, summaries: list[dict]) -> bytes:
    """Accuracy-threshold curves (ADD-S, ADD; 0-10 cm) per method, pooled, rows = modality."""
    plt = _plt()
    th = np.linspace(0, 0.1, 101)
    f, axes = plt.subplots(len(fig.modalities), 2, figsize=(9, 3 * len(fig.modalities)))
    axes = np.atleast_2d(axes)
    for r, mod in enumerate(fig.modalities):
        for c, (k, label) in enumerate(METRICS.items()):
            ax = axes[r, c]
            for m in fig.methods:
                e = [s[k] for s in summaries if s["method"] == m and s["modality"] == mod]
                if e:
                    e = np.concatenate(e)
                    ax.plot(100 * th, [100 * np.mean(e <= t) for t in th], label=m, lw=1.2)
            ax.set_xlabel(f"{label} threshold (cm)")
            ax.set_ylabel("accuracy (%)")
            ax.set_title(f"{label}, {mod}")
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    f.tight_layout()
    return _png(f)


def plot_sequence(fig: Figures, key: str) -> bytes:
    """ADD-S error and alpha over time of every method (seed = the suite's first) on one
    sequence; the target's visible fraction shaded."""
    plt = _plt()
    n = len(fig.modalities)
    f, axes = plt.subplots(2 * n, 1, figsize=(8, 2.2 * 2 * n), sharex=True)
    seed = fig.seeds[0]
    for r, mod in enumerate(fig.modalities):
        ax_e, ax_a = axes[2 * r], axes[2 * r + 1]
        for m in fig.methods:
            s = fig.by_cell[(m, mod)].get(key, {}).get(seed)
            if s is None:
                continue
            x = np.asarray(s["im_id"])
            ax_e.plot(x, np.minimum(100 * s["adds"], 30), label=m, lw=1.1)
            ax_a.plot(x, s["alpha"], label=m, lw=1.1)
            visib = s["visib"]
        ax_e.fill_between(x, 0, 30 * (1 - visib), color="grey", alpha=0.2, lw=0)
        ax_e.set_ylabel(f"ADD-S cm ({mod})")
        ax_e.set_ylim(0, 30)
        ax_a.set_ylabel(f"alpha ({mod})")
        ax_a.set_ylim(-0.05, 1.05)
        for ax in (ax_e, ax_a):
            ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=4)
    axes[0].set_title(f"{key} (seed {seed}; grey: hidden share of the target)")
    axes[-1].set_xlabel("frame")
    f.tight_layout()
    return _png(f)


def _bgr(rgba: tuple) -> tuple[int, int, int]:
    return tuple(int(255 * v) for v in rgba[2::-1])  # type: ignore[return-value]


def _draw_outline(img, V, faces, R, t, K, colour) -> None:
    """Draw on img (BGR) the outline of the mesh (V (M, 3) m, faces) at pose R, t."""
    import cv2

    from chpf.geometry import project_points

    X = V @ R.T + t
    if not np.all(X[:, 2] > 0):
        return
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, list(np.round(project_points(X, K)[faces]).astype(np.int32)), 1)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, colour, 1, cv2.LINE_AA)


def plot_overlays(fig: Figures, seq, frames: list[int], modality: str) -> bytes | None:
    """The frames of one sequence with every method's model outline at its estimate."""
    import cv2

    from chpf.bop import BopDataset, read_results_csv

    root = Path(seq.root)
    if not root.is_dir():
        return None
    ds = BopDataset(root)
    scene = ds.scene("test", seq.scene_id)
    mesh = ds.load_object(seq.obj_id).mesh
    V, Fc = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    seed = fig.seeds[0]
    poses = {}
    for m in fig.methods:
        s = fig.by_cell[(m, modality)].get(seq.key, {}).get(seed)
        if s is None:
            continue
        csvs = sorted(Path(s["dir"]).glob("*.csv"))
        rows = [r for p in csvs if not p.name.startswith("log_") for r in read_results_csv(p)]
        poses[m] = {r.im_id: (r.R, r.t) for r in rows}
    plt = _plt()
    colours = plt.get_cmap("tab10")
    tiles = []
    for im in frames:
        img = scene.rgb(im)[..., ::-1]
        zoom = max(1, round(480 / img.shape[1]))  # small frames are shown larger
        img = np.ascontiguousarray(np.repeat(np.repeat(img, zoom, 0), zoom, 1))
        K = scene.camera(im).K * np.array([[zoom], [zoom], [1.0]])
        K[:2, 2] += (zoom - 1) / 2.0  # pixel centres of the enlarged image
        gt = next((p for p in scene.gt.get(im, []) if p.obj_id == seq.obj_id), None)
        if gt is not None:
            _draw_outline(img, V, Fc, gt.R, gt.t, K, (255, 255, 255))
        for i, m in enumerate(poses):
            if im in poses[m]:
                _draw_outline(img, V, Fc, *poses[m][im], K, _bgr(colours(i % 10)))
        cv2.putText(img, f"frame {im}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255))
        tiles.append(img)
    if not tiles:
        return None
    legend = np.zeros((16, sum(t.shape[1] for t in tiles), 3), np.uint8)
    x = 4
    for i, m in enumerate(["truth", *poses]):
        c = (255, 255, 255) if i == 0 else _bgr(colours((i - 1) % 10))
        cv2.putText(legend, m, (x, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, c)
        x += 10 + 8 * len(m)
    strip = np.concatenate([np.concatenate(tiles, axis=1), legend], axis=0)
    ok, buf = cv2.imencode(".png", strip)
    return buf.tobytes() if ok else None


def _occlusion_order(fig: Figures, seqs) -> list:
    """Sequences from the most occluded (lowest smallest visible fraction, seed-0 jobs)."""
    mins = {}
    for by_key in fig.by_cell.values():
        for key, by_seed in by_key.items():
            for s in by_seed.values():
                mins[key] = float(np.min(s["visib"]))
    return sorted((q for q in seqs if q.key in mins), key=lambda q: (mins[q.key], q.key))


def write_report(out: Path) -> Path:
    """Write ``OUT/report/`` from the finished jobs; returns the report.md path."""
    out = Path(out)
    suite_path = out / SUITE_FILE
    if not suite_path.is_file():
        raise DatasetError(f"{out}: not a chpf-bench folder (no {SUITE_FILE})")
    suite = json.loads(suite_path.read_text(encoding="utf-8"))
    seqs = sequences_from_json(json.loads((out / SEQUENCES_FILE).read_text(encoding="utf-8")))
    summaries = load_summaries(out)
    if not summaries:
        raise DatasetError(f"{out}: no finished jobs to report")
    fig = Figures(suite, summaries)
    rep = out / "report"
    auc = {
        (m, mod, lv, sub, k): fig.auc(m, mod, lv, sub, k)
        for m in fig.methods
        for mod in fig.modalities
        for lv in fig.levels
        for sub in SUBSETS
        for k in METRICS
    }
    track = {(m, mod): fig.tracking(m, mod) for m in fig.methods for mod in fig.modalities}

    head = ["method", "modality", "occlusion", "frames", "metric", "auc", "ci_lo", "ci_hi"]
    head += ["n_sequences", "n_frames_per_seed"]
    rows = [
        [*key[:4], METRICS[key[4]], *_rounded(e), e.n_sequences, e.n_frames]
        for key, e in auc.items()
    ]
    atomic_write_text(rep / "auc.csv", csv_text(rows, head))
    thead = ["method", "modality", "tracked_pct", "ci_lo", "ci_hi", "reacq_s", "losses"]
    thead += ["unrecovered", "fps"]
    trows = [
        [m, mod, *_rounded(t["tracked"]), round(t["reacq_s"], 3), *_counts(t)]
        for (m, mod), t in track.items()
    ]
    atomic_write_text(rep / "tracking.csv", csv_text(trows, thead))
    alpha = {
        key: by_state
        for m in fig.methods
        for mod in fig.modalities
        for key in [(m, mod)]
        if (by_state := fig.alpha_by_state(m, mod)) and any(v[3] for v in by_state.values())
    }
    ahead = ["method", "modality", "state", "alpha", "seed_lo", "seed_hi", "frames"]
    arows = [
        [m, mod, state, *(round(x, 4) for x in v[:3]), v[3]]
        for (m, mod), by_state in alpha.items()
        for state, v in by_state.items()
    ]
    atomic_write_text(rep / "alpha.csv", csv_text(arows, ahead))
    doc = {
        "suite": suite,
        "jobs_done": len(summaries),
        "auc": [dict(zip(head, r, strict=True)) for r in rows],
        "tracking": [dict(zip(thead, r, strict=True)) for r in trows],
        "alpha": [dict(zip(ahead, r, strict=True)) for r in arows],
    }
    atomic_write_text(rep / "report.json", json.dumps(doc, indent=1) + "\n")

    pngs = {"auc_by_level.png": plot_levels(fig, auc), "curves.png": plot_curves(fig, summaries)}
    ordered = _occlusion_order(fig, seqs)
    for q in ordered[: suite["report"]["curve_sequences"]]:
        pngs[f"sequence_{q.key}.png"] = plot_sequence(fig, q.key)
    n_over = suite["report"]["overlay_frames"]
    if ordered and n_over:
        q = ordered[0]
        s = next(iter(fig.by_cell[(fig.methods[0], fig.modalities[0])][q.key].values()))
        worst = int(s["im_id"][int(np.argmin(s["visib"]))])
        last = int(s["im_id"][-1])
        frames = sorted({int(v) for v in np.linspace(worst, last, n_over + 1)[:n_over]})
        png = plot_overlays(fig, q, frames, fig.modalities[0])
        if png is not None:
            pngs["overlays.png"] = png
    for name, data in pngs.items():
        atomic_write_bytes(rep / name, data)

    md = _markdown(suite, fig, auc, track, alpha, len(summaries), len(seqs), pngs, out)
    atomic_write_text(rep / "report.md", md)
    return rep / "report.md"


def _markdown(suite, fig, auc, track, alpha, n_done, n_seqs, pngs, out) -> str:
    sq = suite["sequences"]
    n_jobs = n_seqs * len(suite["methods"]) * len(suite["modalities"]) * len(suite["seeds"])
    timings = out / TIMINGS_FILE
    lines = [
        f"# chpf-bench report: suite `{suite['name']}`",
        "",
        f"{n_done} of {n_jobs} jobs done. Methods: {', '.join(suite['methods'])}; modalities: "
        f"{', '.join(suite['modalities'])}; N = {suite['tracking']['n_particles']} particles, "
        "one likelihood and one phi_cand for all; seeds "
        f"{', '.join(map(str, suite['seeds']))}. Sequences: {sq['scenes_per_level']} scenes x "
        f"occlusion {', '.join(sq['occlusion'])}, {sq['frames']} frames at 30 fps, "
        f"{sq['width']}x{sq['height']}, family `{sq['family']}`, rotation "
        f"{sq['target_rot_speed_deg'] / FPS:.1f} deg/frame; simulated detector boxes.",
        "",
        "Figures: mean over seeds of the AUC (0-10 cm, VOCap, pooled over the frames of the "
        "sequences), [95 % bootstrap interval over sequences, "
        f"{suite['report']['bootstrap']} resamples]. *occl.*: only frames with less than "
        f"{int(100 * OCCLUDED_BELOW)} % of the target visible (scene_gt_info visib_fract). "
        f"*tracked*: frames with ADD-S < {TRACKED_BELOW} diameter; *re-acq.*: mean time from a "
        "loss to the next tracked frame; fps: frames per second of the filter, one worker's "
        "share of the cores.",
        "",
    ]
    if timings.is_file():
        t = json.loads(timings.read_text(encoding="utf-8"))
        lines += [
            f"Last run: {t.get('command', '')!s}: {t['wall_s']:.0f} s wall "
            f"({t['sequences_s']:.0f} s building sequences, {t['jobs_s']:.0f} s for "
            f"{t['jobs_run']} jobs with {t['workers']} worker(s)).",
            "",
        ]
    warned = defaultdict(int)
    for by_key in fig.by_cell.values():
        for by_seed in by_key.values():
            for s in by_seed.values():
                for w in s.get("warnings", []):
                    warned[(s["method"], s["modality"], w.split(":")[0])] += 1
    if warned:
        counts = "; ".join(
            f"{m} {mod}: {k} in {v} job{'s' if v > 1 else ''}" for (m, mod, k), v in warned.items()
        )
        lines += [f"Warnings of the runs (recorded in each job's summary.json): {counts}.", ""]
    lines += ["## All sequences", "", headline_table(fig, auc, track), ""]
    lines += ["## Per occlusion level", "", level_table(fig, auc), ""]
    if alpha:
        lines += [
            "## Doubt: alpha by frame state",
            "",
            "Mean alpha (the share of particles reinvigorated) over the frames of each state, "
            "the mean of the seeds' means (lowest-highest seed; frames over all seeds): "
            f"*tracked* ADD-S < {TRACKED_BELOW} d, *lost* > {LOST_ABOVE} d, *occluded "
            f"tracked* tracked with < {int(100 * OCCLUDED_BELOW)} % visible, *hidden tracked* "
            f"tracked with < {int(100 * HIDDEN_BELOW)} % visible.",
            "",
            alpha_table(fig, alpha),
            "",
        ]
    lines += ["## Figures", ""]
    captions = {
        "auc_by_level.png": "ADD-S AUC by occlusion level (bars: 95 % intervals)",
        "curves.png": "accuracy-threshold curves, all sequences and seeds",
        "overlays.png": "the most occluded sequence: each method's outline at its estimate",
    }
    for name in pngs:
        cap = captions.get(name, f"error and alpha over time, {name[9:-4]}")
        lines += [f"![{cap}]({name})", "", f"*{cap}*", ""]
    lines += ["Tables: `auc.csv`, `tracking.csv`, `alpha.csv`, `report.json`."]
    return "\n".join(lines) + "\n"
