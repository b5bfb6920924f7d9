"""``chpf-train ae|ch --config configs/train_ae.yaml [--trainer.max_steps N] [--ckpt_path CKPT]``.

A ``LightningCLI`` per model type (``ae``: ``AELitModule`` + ``AEDataModule``; ``ch``:
``CHLitModule`` + ``PairDataModule``): YAML configs, every ``--trainer.*`` option (accelerator,
devices, strategy=ddp, num_nodes, precision, max_steps, ...), ``--model.*``, ``--data.*``,
``--checkpoint.*`` (ModelCheckpoint: best by the validation metric + ``last.ckpt``, by default in
``{trainer.default_root_dir}/checkpoints``), CSV and TensorBoard logs in
``trainer.default_root_dir``, and ``--ckpt_path`` to resume (a path, or ``last``).
``--print_config`` prints the full resolved config. ``trainer.precision: null`` (the default
configs) picks bf16 mixed precision where the hardware computes it natively, else float32
(``training.precision``).
"""

from __future__ import annotations

import inspect
import os
import sys
from pathlib import Path
from typing import Any

from chpf.config_schema import Section, load
from chpf.console import run_main
from chpf.errors import ConfigError
from training.precision import auto_precision

USAGE = (
    "usage: chpf-train {ae,ch} --config CONFIG.yaml [--trainer.max_steps N] "
    "[--ckpt_path CKPT|last] [--help]"
)
MONITOR = {"ae": ("val/retrieval_median_deg", "min"), "ch": ("val/auc", "max")}


def _classes(kind: str) -> tuple[type, type]:
    from training.data import AEDataModule, PairDataModule
    from training.lit import AELitModule, CHLitModule

    return (AELitModule, AEDataModule) if kind == "ae" else (CHLitModule, PairDataModule)


def check_model_configs(model_class: type, model_cfg: Any, where: str) -> None:
    """Range and cross-key checks of the model's typed configs (``training.model_config``) in
    the parsed ``model`` namespace: ConfigError naming ``where`` and ``model.<arg>.<key>``
    (LightningCLI has checked the keys and types already)."""
    for name, param in inspect.signature(model_class).parameters.items():
        if isinstance(param.default, Section):
            data = model_cfg[name].as_dict()
            load(type(param.default), data=data, where=where, prefix=f"model.{name}.")


def _make_cli_class(kind: str) -> type:
    from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
    from lightning.pytorch.cli import LightningArgumentParser, LightningCLI
    from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger

    monitor, mode = MONITOR[kind]

    class ChpfTrainCLI(LightningCLI):
        """LightningCLI with checkpoint defaults, CSV + TensorBoard loggers and --ckpt_path."""

        def add_arguments_to_parser(self, parser: LightningArgumentParser) -> None:
            parser.add_argument(
                "--ckpt_path",
                type=str | None,
                default=None,
                help="checkpoint to resume from (path, or 'last')",
            )
            parser.add_lightning_class_args(ModelCheckpoint, "checkpoint")
            parser.set_defaults(
                {
                    "checkpoint.monitor": monitor,
                    "checkpoint.mode": mode,
                    "checkpoint.save_top_k": 1,
                    "checkpoint.save_last": True,
                    "checkpoint.filename": "best-{step}",
                    "checkpoint.auto_insert_metric_name": False,
                    "trainer.default_root_dir": f"runs/{kind}",
                }
            )

        def before_instantiate_classes(self) -> None:
            cfg = self.config
            check_model_configs(self.model_class, cfg["model"], f"chpf-train {kind}")
            root = cfg["trainer.default_root_dir"] or os.getcwd()
            if cfg["checkpoint.dirpath"] is None:
                cfg["checkpoint.dirpath"] = str(Path(root) / "checkpoints")
            if cfg["trainer.precision"] is None:
                cfg["trainer.precision"] = auto_precision(cfg["trainer.accelerator"])
                print(f"trainer.precision: {cfg['trainer.precision']} (chosen for this machine)")

        def instantiate_trainer(self, **kwargs: Any) -> Any:
            trainer_cfg = self._get(self.config_init, "trainer", default={})
            if trainer_cfg.get("logger") in (None, True):
                root = trainer_cfg.get("default_root_dir") or os.getcwd()
                kwargs["logger"] = [
                    CSVLogger(root, name="logs"),
                    TensorBoardLogger(root, name="tb", default_hp_metric=False),
                ]
                callbacks = list(trainer_cfg.get("callbacks") or [])
                if not any(isinstance(c, LearningRateMonitor) for c in callbacks):
                    kwargs["callbacks"] = [*callbacks, LearningRateMonitor("step")]
            return super().instantiate_trainer(**kwargs)

    return ChpfTrainCLI


def _check_resume(kind: str, ckpt_path: str | None) -> None:
    from training.checkpoints import checkpoint_info

    if ckpt_path is None or ckpt_path in ("last", "best", "hpc", "registry"):
        return
    checkpoint_info(ckpt_path, expect=kind)


def make_cli(kind: str, args: list[str]) -> Any:
    """The ``LightningCLI`` of ``chpf-train kind args``: config parsed and checked, model,
    data module and trainer instantiated, nothing run."""
    import warnings

    model_class, data_class = _classes(kind)
    cli_class = _make_cli_class(kind)
    warnings.filterwarnings("ignore", message=".*does not have many workers.*")
    warnings.filterwarnings("ignore", message=".*args parameter is intended to run from within.*")
    warnings.filterwarnings("ignore", message=".*isinstance.treespec, LeafSpec.*")
    warnings.filterwarnings("ignore", message=".*Checkpoint directory .* exists and is not empty.*")
    return cli_class(
        model_class,
        data_class,
        args=args,
        run=False,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        auto_configure_optimizers=False,
        parser_kwargs={"prog": f"chpf-train {kind}"},
    )


def train(kind: str, args: list[str]) -> dict[str, str | None]:
    """Run ``chpf-train kind args``; returns ``{"best": path, "last": path}``."""
    from lightning.pytorch.callbacks import ModelCheckpoint

    cli = make_cli(kind, args)
    ckpt_path = cli.config["ckpt_path"]
    _check_resume(kind, ckpt_path)
    trainer = cli.trainer
    trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path=ckpt_path)
    ckpt_cb = next(c for c in trainer.callbacks if isinstance(c, ModelCheckpoint))
    last = Path(ckpt_cb.dirpath) / "last.ckpt"
    trainer.save_checkpoint(last, weights_only=False)  # final state, whatever the val schedule
    best = ckpt_cb.best_model_path or None
    if trainer.is_global_zero:
        print(f"best checkpoint: {best}\nlast checkpoint: {last}")
    return {"best": best, "last": str(last)}


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``chpf-train {ae,ch} ...``; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        print("  ae: train the autoencoder likelihood; ch: the Counter-Hypothetical classifier")
        print("  'chpf-train ae --help' lists every option.")
        return 0 if argv else 2
    kind, rest = argv[0], argv[1:]
    if kind not in MONITOR:
        raise ConfigError(f"unknown model type '{kind}' (expected 'ae' or 'ch')")
    train(kind, rest)
    return 0


cli = run_main(main)

if __name__ == "__main__":
    cli()
