"""Device selection (chpf.providers), tested on a CPU-only machine with the providers mocked."""

from __future__ import annotations

import pytest

from chpf.bundle import Bundle
from chpf.errors import ConfigError
from chpf.providers import CPU, CUDA, TENSORRT, describe, execution_providers
from chpf.tracking.demo import shipped_bundle
from chpf.tracking.tracker import Tracker


def test_cpu_auto_and_cuda_pick_the_providers_that_exist():
    cpu_only, gpu, trt = [CPU], [CUDA, CPU], [TENSORRT, CUDA, CPU]
    assert execution_providers("cpu", trt) == [CPU]
    assert execution_providers("auto", cpu_only) == [CPU]
    assert execution_providers("auto", gpu) == [CUDA, CPU]
    assert execution_providers("cuda", trt) == [TENSORRT, CUDA, CPU]
    with pytest.raises(ConfigError, match=r"device cuda: .*no CUDA provider.*chpf\[gpu\]"):
        execution_providers("cuda", cpu_only)
    with pytest.raises(ConfigError, match="unknown device 'tpu'"):
        execution_providers("tpu", gpu)
    assert describe([CUDA, CPU]).startswith("GPU") and describe([CPU]).startswith("CPU")


def test_bundle_and_tracker_run_where_they_are_told(monkeypatch):
    bundle = Bundle.load(shipped_bundle(), device="cpu")
    assert bundle.providers == [CPU] and bundle.device == "cpu"
    tracker = Tracker.from_bundle(bundle, device="auto")  # no GPU here: the same sessions
    assert tracker.bundle is bundle
    monkeypatch.setattr("onnxruntime.get_available_providers", lambda: [CPU])
    with pytest.raises(ConfigError, match="device cuda"):
        Tracker.from_bundle(shipped_bundle(), device="cuda")
