"""Where the networks run: onnxruntime execution providers for a device choice.

``cpu`` is onnxruntime's CPU provider; ``cuda`` its CUDA provider (TensorRT's first where the
installed onnxruntime has it), which needs ``onnxruntime-gpu`` (``pip install 'chpf[gpu]'``)
and an NVIDIA GPU; ``auto`` is ``cuda`` when that provider is there, else ``cpu``.
"""

from __future__ import annotations

from collections.abc import Sequence

import onnxruntime as ort

from chpf.errors import ConfigError

DEVICES = ("auto", "cpu", "cuda")
CPU = "CPUExecutionProvider"
CUDA = "CUDAExecutionProvider"
TENSORRT = "TensorrtExecutionProvider"


def execution_providers(device: str, available: Sequence[str] | None = None) -> list[str]:
    """The providers (first preferred) for ``device`` (DEVICES) given the ``available`` ones
    (None: onnxruntime's); ConfigError (one line) for ``cuda`` without a CUDA provider."""
    if device not in DEVICES:
        raise ConfigError(f"unknown device {device!r} (choose from {', '.join(DEVICES)})")
    have = list(ort.get_available_providers() if available is None else available)
    if device == "cpu" or (device == "auto" and CUDA not in have):
        return [CPU]
    if CUDA not in have:
        raise ConfigError(
            f"device cuda: this onnxruntime has no CUDA provider (it has {', '.join(have)}); "
            "install chpf[gpu] (onnxruntime-gpu) on a machine with an NVIDIA GPU, or use cpu"
        )
    return [p for p in (TENSORRT, CUDA) if p in have] + [CPU]


def describe(providers: Sequence[str]) -> str:
    """One phrase saying where the networks run, e.g. "GPU (CUDAExecutionProvider)"."""
    return f"{'GPU' if providers[0] != CPU else 'CPU'} ({providers[0]})"
