"""Budget -> stage sizes. The split follows docs/shipped-bundle.md's recipe, scaled."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from chpf.errors import ConfigError

# share of the budget per stage group (README, "chpf-make-bundle")
SPLIT = {"data": 0.25, "ae": 0.25, "ch": 0.30, "rest": 0.20}
# nominal rates of the shipped recipe on a 2-core bf16 CPU (docs/shipped-bundle.md)
PAIRS_PER_S = 600_000 / (18 * 60)  # pairs with the pool's rendering
AE_STEPS_PER_S = 5000 / 600
CH_STEPS_PER_S = 11758 / 1170


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
    ae_config: str = "configs/train_ae.yaml"
    ch_config: str = "configs/train_ch.yaml"
    extra_gen: list[str] = field(default_factory=list)

    def rows(self) -> list[tuple[str, str, float]]:
        """(stage, size, estimated minutes)."""
        b = self.budget_s / 60
        d = b * SPLIT["data"]
        r = b * SPLIT["rest"]
        return [
            ("ae_data", f"{self.ae_n} samples / {self.ae_pool} renders", d * 0.15),
            ("pairs_data", f"{self.pairs_n} pairs / {self.pairs_pool} renders", d * 0.75),
            (
                "heldout",
                f"{self.test_n} ae + {self.test_n} pairs / {self.test_pool} renders",
                d * 0.1,
            ),
            ("train_ae", f"<= {self.ae_steps} steps, <= {self.ae_time_s} s", b * SPLIT["ae"]),
            ("codebook", f"{self.codebook_k} views", r * 0.1),
            ("train_ch", f"<= {self.ch_steps} steps, <= {self.ch_time_s} s", b * SPLIT["ch"]),
            ("export", f"K = {self.export_k}", r * 0.35),
            ("evaluate", f"{self.test_n} crops + pairs", r * 0.25),
            ("sequence", f"1 scene x {self.seq_frames} frames", r * 0.05),
            ("track", "CH-PF + PoseRBPF", r * 0.25),
        ]


# a 12-triangle box at 64x64 on this CPU, one process (DESIGN.md: ~2 ms per crop)
NOMINAL_RENDERS_PER_S = 500.0


def make_plan(budget_s: float, preset: str | None = None, rates=None, workers: int = 2) -> Plan:
    """``rates`` (make_bundle.measure.Rates, or None for the nominal rates) scales the sizes:
    data by the measured render rate (never above the recipe's), training steps by the
    measured autoencoder step rate."""
    if preset == "tiny":
        return Plan(
            preset="tiny", budget_s=budget_s, crop_size=32, ae_n=64, ae_pool=48, pairs_n=64,
            pairs_pool=48, test_n=32, test_pool=24, codebook_k=64, export_k=64, ae_steps=4,
            ae_time_s=60, ch_steps=4, ch_time_s=60, seq_frames=4,
            ae_config="configs/train_ae_tiny.yaml", ch_config="configs/train_ch_tiny.yaml",
            extra_gen=["--set", "occluder_pool.num_entries=12"],
        )  # fmt: skip
    if preset is not None:
        raise ConfigError(f"--preset: only 'tiny' exists, got {preset!r}")
    if budget_s < 300:
        raise ConfigError("--budget: at least 5m (use --preset tiny for a smoke test)")
    d = budget_s * SPLIT["data"]
    f_render, ae_rate, ch_rate = 1.0, AE_STEPS_PER_S, CH_STEPS_PER_S
    if rates is not None:
        per_s = rates.renders_per_s * min(max(workers, 1), 2) / 2
        f_render = min(1.0, max(0.1, per_s / NOMINAL_RENDERS_PER_S))
        ae_rate = rates.ae_steps_per_s
        ch_rate = CH_STEPS_PER_S * ae_rate / AE_STEPS_PER_S
    pairs_n = int(PAIRS_PER_S * f_render * d * 0.75)
    ae_n = min(60_000, int(PAIRS_PER_S * f_render * d * 0.15 * 1.5))
    ae_time = int(budget_s * SPLIT["ae"])
    ch_time = int(budget_s * SPLIT["ch"])
    return Plan(
        preset="budget", budget_s=budget_s, crop_size=64, ae_n=ae_n,
        ae_pool=max(1000, min(10_000, ae_n // 6)), pairs_n=pairs_n,
        pairs_pool=max(2000, min(120_000, pairs_n // 5)), test_n=2000, test_pool=1000,
        codebook_k=20_000 if budget_s >= 3600 else 4096,
        export_k=10_000 if budget_s >= 3600 else 4096,
        ae_steps=max(100, min(5000, int(ae_rate * ae_time))), ae_time_s=ae_time,
        ch_steps=max(100, min(15000, int(ch_rate * ch_time))), ch_time_s=ch_time,
        seq_frames=60,
    )  # fmt: skip


def format_plan(plan: Plan) -> str:
    lines = ["| stage | size | est. min |", "| --- | --- | --- |"]
    lines += [f"| {s} | {z} | {m:.1f} |" for s, z, m in plan.rows()]
    return "\n".join(lines)
