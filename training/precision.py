"""``trainer.precision: null`` -> a precision that is fast on the machine at hand.

bfloat16 mixed precision speeds training up on CPUs with bf16 units (Intel AMX or
AVX512-BF16: 0.18 instead of 0.30 s per autoencoder step, batch 64, on an AMX machine) but is
emulated, and about ten times *slower*, on CPUs without them (an AVX2-only AMD EPYC: 3.1
instead of 0.30 s). So the default configs leave the choice to the hardware; an explicit
``--trainer.precision`` always wins.
"""

from __future__ import annotations

from pathlib import Path

BF16_CPU_FLAGS = ("amx_bf16", "avx512_bf16")


def cpu_flags(cpuinfo: str | Path = "/proc/cpuinfo") -> set[str]:
    """The CPU feature flags listed in ``cpuinfo`` (empty where there is no such file)."""
    try:
        text = Path(cpuinfo).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return set(value.split())
    return set()


def cpu_has_bf16(flags: set[str] | None = None) -> bool:
    """True if the CPU computes bfloat16 natively (AMX or AVX512-BF16)."""
    flags = cpu_flags() if flags is None else flags
    return any(f in flags for f in BF16_CPU_FLAGS)


def auto_precision(accelerator: str | None, flags: set[str] | None = None) -> str:
    """Lightning precision for ``trainer.precision: null`` on ``accelerator``.

    CPU: "bf16-mixed" with native bf16 units, else "32-true". GPU ("gpu", "cuda", or "auto"
    with CUDA present): "bf16-mixed" where the GPU supports it, else "16-mixed".
    """
    acc = (accelerator or "auto").lower()
    if acc in ("gpu", "cuda", "auto"):
        import torch

        if torch.cuda.is_available():
            return "bf16-mixed" if torch.cuda.is_bf16_supported() else "16-mixed"
        if acc != "auto":
            return "32-true"
    if acc in ("cpu", "auto"):
        return "bf16-mixed" if cpu_has_bf16(flags) else "32-true"
    return "32-true"
