"""chpf-train with ``--trainer.strategy ddp --trainer.devices 2 --trainer.accelerator cpu`` (two
processes, gloo) on tiny data: each rank sees its own samples, validation gathers unequal
per-rank counts (empty crops are left out on one rank only), and the checkpoint loads."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from training.checkpoints import load_autoencoder

ROOT = Path(__file__).resolve().parents[2]
AE_CFG = str(ROOT / "configs" / "train_ae_tiny.yaml")

# Lightning's DDP launcher re-runs this script for rank 1, so both ranks record the global
# sample indices their loaders read (train and validation sets told apart by their size).
PROBE = """
import os, sys
from training import data
from training.cli import main

_get = data.ShardSamples.__getitem__

def _probe(self, i):
    rank = os.environ.get("LOCAL_RANK", "0")
    with open(os.path.join(os.environ["PROBE_DIR"], f"rank{rank}_n{len(self)}.txt"), "a") as f:
        f.write(f"{int(self.indices[i])}\\n")
    return _get(self, i)

data.ShardSamples.__getitem__ = _probe
sys.exit(main(sys.argv[1:]))
"""


def _seen(probe: Path, rank: int, n: int) -> list[int]:
    path = probe / f"rank{rank}_n{n}.txt"
    return [int(v) for v in path.read_text().split()] if path.is_file() else []


def test_ddp_two_cpu_processes(ae_dir: Path, tmp_path: Path) -> None:
    # empty crops (visib_fract 0) at every 4th sample: the validation sampler hands rank 0 the
    # even positions, so rank 0 keeps 4 of its 8 validation crops for retrieval, rank 1 all 8
    for shard in sorted(ae_dir.glob("*.npz")):
        with np.load(shard) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["visib_fract"][::4] = 0.0
        np.savez(shard, **arrays)
    script = tmp_path / "probe_train.py"
    script.write_text(PROBE)
    probe = tmp_path / "probe"
    probe.mkdir()
    out = tmp_path / "run"
    env = {
        **os.environ,
        "PROBE_DIR": str(probe),
        "CHPF_CACHE": str(tmp_path / "cache"),
        "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
        "OMP_NUM_THREADS": "1",
    }
    cmd = [sys.executable, str(script), "ae", "--config", AE_CFG, "--data.data_dir", str(ae_dir)]
    cmd += ["--trainer.default_root_dir", str(out), "--trainer.strategy", "ddp"]
    cmd += ["--trainer.devices", "2", "--trainer.accelerator", "cpu", "--trainer.max_steps", "3"]
    res = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    # 64 samples in 4 shards of 16: one shard held out for validation, 48 for training; each
    # rank reads 24 training samples (3 steps of 8), none of the other rank's
    train = [_seen(probe, r, 48) for r in (0, 1)]
    assert len(train[0]) == len(train[1]) == 24, train
    assert not set(train[0]) & set(train[1])
    val = [_seen(probe, r, 16) for r in (0, 1)]
    assert val[0] and val[1] and not set(val[0]) & set(val[1]), val
    model, _ = load_autoencoder(out / "checkpoints" / "last.ckpt")
    assert model(torch.rand(2, 3, 16, 16))[1].shape == (2, 16)
    assert torch.load(out / "checkpoints" / "last.ckpt", weights_only=False)["global_step"] == 3
