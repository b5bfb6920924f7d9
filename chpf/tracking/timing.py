"""Per-stage timing helpers (milliseconds)."""

from __future__ import annotations

import time


def ms_since(t0: float) -> float:
    """Milliseconds elapsed since ``t0 = time.perf_counter()``."""
    return (time.perf_counter() - t0) * 1000.0


def add_ms(acc: dict[str, float], stage_ms: dict[str, float]) -> None:
    """Accumulate per-stage milliseconds into ``acc``."""
    for k, v in stage_ms.items():
        acc[k] = acc.get(k, 0.0) + float(v)
