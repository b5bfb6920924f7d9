"""What this machine does in a few seconds: renders per second and autoencoder steps per second
(with the precision the training will use), to size the plan's stages."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Rates:
    renders_per_s: float  # one process
    ae_steps_per_s: float
    precision: str


def measure_render(obj, size: int, seconds: float = 2.0) -> float:
    from chpf.crops import CropSpec, render_crops
    from chpf.render import Renderer

    spec = CropSpec.for_object(obj.diameter, size)
    rend = Renderer(size, size)
    rng = np.random.default_rng(0)
    n, t0 = 0, None
    while True:
        q = rng.normal(size=(16, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        w, x, y, z = q.T
        R = np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
            ],
            1,
        )
        render_crops(rend, obj, R, spec)
        if t0 is None:  # the first batch warms the GL context up
            t0 = time.perf_counter()
            continue
        n += len(R)
        if time.perf_counter() - t0 >= seconds:
            return n / (time.perf_counter() - t0)


def measure_ae_steps(
    trainer_args: list[str], seconds: float = 3.0, warmup: int = 3
) -> tuple[float, str]:
    """(autoencoder training steps per second, precision): ``warmup`` steps (kernel set-up)
    are not timed, then steps run for at least ``seconds`` (and at least 3 steps), in the
    config's memory format. A rough figure: on this 2-core CPU the first two bf16 steps took
    7-9 s each and later ones 1-1.7 s, with single steps of 9-10 s when other jobs ran, so a
    few seconds' reading is 2x off either way; it only sizes the step caps, a guard (plan.py:
    the trainings run to their max_time)."""
    import torch
    import yaml

    from training.model_config import EncoderConfig
    from training.models import Autoencoder
    from training.precision import auto_precision

    cfg = yaml.safe_load((ROOT / "configs" / "train_ae.yaml").read_text())
    acc = next((a.split("=", 1)[1] for a in trainer_args if a.startswith("--trainer.accel")), None)
    if acc is None and "--trainer.accelerator" in trainer_args:
        acc = trainer_args[trainer_args.index("--trainer.accelerator") + 1]
    acc = acc or cfg["trainer"].get("accelerator", "cpu")
    prec = cfg["trainer"].get("precision") or auto_precision(acc)
    dev = "cuda" if acc in ("gpu", "cuda") and torch.cuda.is_available() else "cpu"
    model = Autoencoder(EncoderConfig(**cfg["model"]["encoder"])).to(dev)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    bs = int(cfg["data"]["batch_size"])
    s = model.config.size
    x = torch.rand(bs, 3, s, s, device=dev)
    if cfg["model"].get("channels_last", True):
        model = model.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    dtype = torch.bfloat16 if prec.startswith("bf16") else torch.float16

    def step() -> None:
        with torch.autocast(dev, dtype=dtype, enabled=prec.endswith("mixed")):
            recon, _ = model(x)
            loss = torch.nn.functional.mse_loss(recon.float(), model.recon_target(x))
        opt.zero_grad()
        loss.backward()
        opt.step()
        if dev == "cuda":
            torch.cuda.synchronize()

    for _ in range(warmup):
        step()
    n, t0 = 0, time.perf_counter()
    while n < 3 or time.perf_counter() - t0 < seconds:
        step()
        n += 1
    return n / (time.perf_counter() - t0), prec


def measure(obj, size: int, trainer_args: list[str]) -> Rates:
    r = measure_render(obj, size)
    st, prec = measure_ae_steps(trainer_args)
    return Rates(renders_per_s=r, ae_steps_per_s=st, precision=prec)
