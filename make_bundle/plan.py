"""Budget -> stage sizes. The split follows docs/shipped-bundle.md's recipe, scaled."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from chpf.errors import ConfigError

# shares of the budget left after the fixed costs (README, "chpf-make-bundle")
SPLIT = {"data": 0.25, "ae": 0.25, "ch": 0.30}
MARGIN = 0.05  # of the budget, kept free for what the estimates miss
# nominal rates of the shipped recipe on a 2-core bf16 CPU (docs/shipped-bundle.md)
PAIRS_PER_S = 600_000 / (18 * 60)  # pairs with the pool's rendering
AE_STEPS_PER_S = 5000 / 600
CH_STEPS_PER_S = 11758 / 1170
# seconds each stage costs besides its sized work (process start-ups, loading models and data,
# the validation codebook and the last validation after max_time, writing): a 10-minute box run
# on this 2-core CPU at load 5-6 took train_ae 25 s beyond its max_time, train_ch 9 s, codebook
# 0.2 s, export 5 s, evaluate 21 s, sequence 3 s, track 4 s (README, "chpf-make-bundle");
# rounded up for slower meshes
OVERHEAD_S = {
    "ae_data": 10, "pairs_data": 10, "heldout": 15, "train_ae": 30, "codebook": 5,
    "train_ch": 15, "export": 15, "evaluate": 60, "sequence": 10, "track": 10,
}  # fmt: skip
TRAIN_MIN_S = 20  # a training stage never gets less max_time than this
# A training stage runs to its max_time: its learning-rate schedule follows the time
# (lr_schedule_by_time), and its step cap is this many times the steps the probe expects, only a
# guard. A few seconds' probe on a shared CPU read 0.28 autoencoder steps/s where the training
# then ran 0.65 (README), and a cap sized from it stopped the classifier after 83 of its 132 s.
STEP_CAP_FACTOR = 4
DEFAULT_BUDGET_S = 5400  # --budget's default, 90 min
SHORT_BUDGET_S = 1800  # below it: smaller held-out sets, codebooks and test sequence
# (samples, renders) of each held-out set: about 1,000 hard negatives (20-45 deg) among the
# pairs, so that the hard-negative AUC's 95 % interval is about 0.02 wide (the duck's 0.936:
# 0.926-0.944); 2,000 pairs from 1,000 renders, the size before 2026-12-07, hold about 260 (the
# same classifier on them: 0.927, 0.906-0.946)
HELDOUT = (8000, 4000)
# the autoencoder's validation crops: from its training pool, cut without crop jitter (the
# training crops' jitter, which their targets follow, made its retrieval error read the shift)
AE_VAL_N = 2000


def parse_budget(text: str) -> float:
    """'90m', '1h30m', '10m', '45s' -> seconds."""
    m = re.fullmatch(r"\s*(?:(\d+)h)?\s*(?:(\d+)m)?\s*(?:(\d+)s)?\s*", text or "")
    if not m or not any(m.groups()):
        raise ConfigError(f"--budget: expected e.g. 90m, 1h30m, 45s, got {text!r}")
    h, mi, s = (int(g or 0) for g in m.groups())
    return float(h * 3600 + mi * 60 + s)


@dataclass
class Plan:
    preset: str
    budget_s: float
    crop_size: int
    ae_n: int
    ae_pool: int
    pairs_n: int
    pairs_pool: int
    test_n: int
    test_pool: int
    codebook_k: int
    export_k: int
    ae_steps: int
    ae_time_s: int
    ch_steps: int
    ch_time_s: int
    seq_frames: int
    est_s: dict[str, float] = field(default_factory=dict)  # estimated seconds per stage
    ae_val_n: int = 0  # crops without crop jitter to validate the autoencoder on (0: its split)
    ae_config: str = "configs/train_ae.yaml"
    ch_config: str = "configs/train_ch.yaml"
    extra_gen: list[str] = field(default_factory=list)

    def sizes(self) -> dict[str, str]:
        """Stage -> what it makes, in words."""
        t = self.test_n
        return {
            "ae_data": f"{self.ae_n} samples / {self.ae_pool} renders"
            + (f", {self.ae_val_n} to validate" if self.ae_val_n else ""),
            "pairs_data": f"{self.pairs_n} pairs / {self.pairs_pool} renders",
            "heldout": f"{t} ae + {t} pairs / {self.test_pool} renders",
            "train_ae": f"{self.ae_time_s} s (<= {self.ae_steps} steps)",
            "codebook": f"{self.codebook_k} views",
            "train_ch": f"{self.ch_time_s} s (<= {self.ch_steps} steps)",
            "export": f"K = {self.export_k}",
            "evaluate": f"{t} crops + pairs",
            "sequence": f"1 scene x {self.seq_frames} frames",
            "track": "CH-PF + PoseRBPF",
        }

    def rows(self) -> list[tuple[str, str, float]]:
        """(stage, size, estimated minutes)."""
        return [(k, v, self.est_s.get(k, 0.0) / 60) for k, v in self.sizes().items()]

    def after(self, stage: str) -> float:
        """Estimated seconds of the stages after ``stage``."""
        names = list(self.sizes())
        return sum(self.est_s.get(k, 0.0) for k in names[names.index(stage) + 1 :])


# what measure_render reads, one process, on the 2-core CPU where PAIRS_PER_S was measured: on a
# quiet machine it read 254 and 178 renders/s for the box, 228 for the mug, 214 and 267 for
# pybullet's 4k-triangle textured duck, whose pairs stage then composed 592 pairs/s (PAIRS_PER_S:
# 556). The 500 this was before (DESIGN.md's ~2 ms per crop) planned the duck's pairs at half
# the rate they ran: the data stages took 11 of their 25 minutes, with a pool of 72,072 renders
# where the recipe's has 120,000.
NOMINAL_RENDERS_PER_S = 250.0


def _tiny(budget_s: float) -> Plan:
    return Plan(
        preset="tiny", budget_s=budget_s, crop_size=32, ae_n=64, ae_pool=48, pairs_n=64,
        pairs_pool=48, test_n=32, test_pool=24, ae_val_n=32, codebook_k=64, export_k=64, ae_steps=4,
        ae_time_s=60, ch_steps=4, ch_time_s=60, seq_frames=4,
        est_s={"ae_data": 2, "pairs_data": 1, "heldout": 1, "train_ae": 12, "codebook": 1,
               "train_ch": 9, "export": 3, "evaluate": 4, "sequence": 1, "track": 1},
        ae_config="configs/train_ae_tiny.yaml", ch_config="configs/train_ch_tiny.yaml",
        extra_gen=["--set", "occluder_pool.num_entries=12", "--samples-per-shard", "16"],
    )  # fmt: skip


def make_plan(
    budget_s: float,
    preset: str | None = None,
    rates=None,
    workers: int = 2,
    spent_s: float = 0.0,
) -> Plan:
    """Stage sizes that fit ``budget_s`` seconds, of which ``spent_s`` are gone (measuring).

    The fixed costs (``OVERHEAD_S``, the held-out sets, the export's codebook renders) and a
    ``MARGIN`` come off first; the rest is split by ``SPLIT``. ``rates``
    (make_bundle.measure.Rates, or None for the nominal rates) scales the data sizes by the
    measured render rate (never above the recipe's); every training runs to its ``max_time``
    share (its step cap, ``STEP_CAP_FACTOR`` times the measured step rate's, is a guard).
    """
    if preset == "tiny":
        return _tiny(budget_s)
    if preset is not None:
        raise ConfigError(f"--preset: only 'tiny' exists, got {preset!r}")
    if budget_s < 300:
        raise ConfigError("--budget: at least 5m (use --preset tiny for a smoke test)")
    f_render, ae_rate, ch_rate = 1.0, AE_STEPS_PER_S, CH_STEPS_PER_S
    renders_per_s = NOMINAL_RENDERS_PER_S * 2
    if rates is not None:
        renders_per_s = rates.renders_per_s * min(max(workers, 1), 2)
        f_render = min(1.0, max(0.1, renders_per_s / 2 / NOMINAL_RENDERS_PER_S))
        ae_rate = rates.ae_steps_per_s
        ch_rate = CH_STEPS_PER_S * ae_rate / AE_STEPS_PER_S
    pairs_per_s = PAIRS_PER_S * f_render
    short = budget_s < SHORT_BUDGET_S
    test_n, test_pool = (2000, 1000) if short else HELDOUT
    codebook_k = 4096 if budget_s < 3600 else 20_000
    export_k = 4096 if budget_s < 3600 else 10_000
    est = dict(OVERHEAD_S)
    est["heldout"] += (2 * test_n + 2 * test_pool) / pairs_per_s
    est["ae_data"] += AE_VAL_N / pairs_per_s
    if export_k != codebook_k:  # the export renders its own codebook views
        est["export"] += export_k / renders_per_s
    free = budget_s * (1 - MARGIN) - spent_s - sum(est.values())
    if free < 4 * TRAIN_MIN_S:
        raise ConfigError(
            f"--budget: {budget_s / 60:.0f} min leave {free:.0f} s for data and training on "
            "this machine after the fixed costs; give a larger budget"
        )
    share = {k: free * v / sum(SPLIT.values()) for k, v in SPLIT.items()}
    pairs_n = int(pairs_per_s * share["data"] * 5 / 6)
    ae_n = min(60_000, int(pairs_per_s * share["data"] / 6 * 1.5))
    ae_time, ch_time = int(share["ae"]), int(share["ch"])
    est["ae_data"] += share["data"] / 6
    est["pairs_data"] += share["data"] * 5 / 6
    est["train_ae"] += ae_time
    est["train_ch"] += ch_time
    return Plan(
        preset="budget", budget_s=budget_s, crop_size=64, ae_n=ae_n,
        ae_pool=max(1000, min(10_000, ae_n // 6)), pairs_n=pairs_n,
        pairs_pool=max(2000, min(120_000, pairs_n // 5)), test_n=test_n, test_pool=test_pool,
        ae_val_n=AE_VAL_N, codebook_k=codebook_k, export_k=export_k,
        ae_steps=max(100, int(STEP_CAP_FACTOR * ae_rate * ae_time)), ae_time_s=ae_time,
        ch_steps=max(100, int(STEP_CAP_FACTOR * ch_rate * ch_time)), ch_time_s=ch_time,
        seq_frames=30 if short else 60, est_s={k: round(v, 1) for k, v in est.items()},
    )  # fmt: skip


def format_plan(plan: Plan) -> str:
    lines = ["| stage | size | est. min |", "| --- | --- | --- |"]
    lines += [f"| {s} | {z} | {m:.1f} |" for s, z, m in plan.rows()]
    total = sum(plan.est_s.values()) / 60
    lines.append(f"| total | of {plan.budget_s / 60:.0f} min | {total:.1f} |")
    return "\n".join(lines)
