"""LightningModules: the autoencoder likelihood (``AELitModule``) and the CH classifier
(``CHLitModule``).

Both accept the batches of ``training.data`` (uint8 RGB ``(B,S,S,3)``), train with Adam and a
linear-warmup + cosine learning-rate decay, and write a ``"chpf"`` entry into every checkpoint
(model type, model config, crop spec of the data; see ``training.checkpoints``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
import torch.nn.functional as F

from chpf.config_schema import to_dict
from chpf.errors import ChpfError, ConfigError, DatasetError
from data_gen.compose import depth_off
from data_gen.config import data_pairs_config, shifts_ae_targets
from training.batch_augment import BatchAugment, augment_batch
from training.checkpoints import (
    CHECKPOINT_FORMAT_VERSION,
    checkpoint_info,
    load_autoencoder,
    state_sha256,
)
from training.extra_pairs import CandidateCodebook
from training.metrics import (
    cosine_retrieval,
    retrieval_summary,
    roc_auc,
    symmetry_aware_angle,
)
from training.model_config import (
    ClassifierConfig,
    EncoderConfig,
    PairsMix,
    from_stored,
    mix_overrides,
)
from training.models import Autoencoder, CHClassifier, Preprocess

# Default configs of the modules' signatures (shared instances: the modules never change them).
DEFAULT_ENCODER = EncoderConfig()
DEFAULT_CLASSIFIER = ClassifierConfig()
NO_MIX = PairsMix()
NO_AUGMENT = BatchAugment()

# ----------------------------------------------------------------------------- shared pieces


def bootstrapped_l2(recon: torch.Tensor, target: torch.Tensor, ratio: float = 0.25) -> torch.Tensor:
    """Bootstrapped L2 (Augmented Autoencoder): mean of the worst ``ratio`` of pixel errors.

    ``recon``, ``target``: ``(B, 3, S, S)``. A pixel's error is its squared difference averaged
    over the 3 channels; per image the ``ceil(ratio * S * S)`` largest are averaged, then the
    images are averaged. ``ratio = 1`` gives the plain per-pixel MSE.
    """
    if not 0.0 < ratio <= 1.0:
        raise ConfigError(f"bootstrap_ratio must be in (0, 1], got {ratio}")
    err = (recon - target).pow(2).mean(dim=1).flatten(1)  # (B, S*S)
    k = max(1, math.ceil(ratio * err.shape[1]))
    if k < err.shape[1]:
        err = torch.topk(err, k, dim=1, sorted=False).values
    return err.mean()


def empty_separation(
    z: torch.Tensor, empty: torch.Tensor, margin: float, views: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean ``relu(cos - margin)`` between the embeddings ``z`` (B,E) of empty crops (``empty``
    (B,) bool: no object in the crop) and those of the batch's crops that show the object,
    plus the extra view embeddings ``views`` (V,E) if given (e.g. of the clean targets).

    The cosine ignores the embedding's norm, so an empty crop, which the decoder only has to
    turn into black, can otherwise point anywhere, also close to some view of the codebook.
    """
    others = z[~empty] if views is None else torch.cat([z[~empty], views])
    if not bool(empty.any()) or others.shape[0] == 0:
        return z.sum() * 0.0
    return F.relu(F.normalize(z[empty], dim=1) @ F.normalize(others, dim=1).T - margin).mean()


def view_separation(
    z: torch.Tensor, views: torch.Tensor, far: torch.Tensor, margin: float
) -> torch.Tensor:
    """Mean over the crops of ``relu(max_j cos(z_i, views_j) - margin)``, j over the pairs
    ``far`` (B,V) bool: the embedding ``z_i`` (B,E) of an augmented crop against the hardest
    clean-view embedding ``views_j`` (V,E) of an orientation far from crop i's (more than
    ``view_min_angle_deg`` apart, up to symmetry). Crops without a far view count as 0.

    Reconstruction alone leaves look-alike views far apart in orientation (a mug's front and
    back) close in the embedding; this term is what the codebook look-up needs: a crop's cosine
    to the views of other orientations stays below ``margin``.
    """
    if not bool(far.any()):
        return z.sum() * 0.0
    cos = F.normalize(z, dim=1) @ F.normalize(views, dim=1).T
    hardest = cos.masked_fill(~far, -1.0).max(dim=1).values
    return F.relu(hardest - margin).mean()


def view_matching(
    z: torch.Tensor, views: torch.Tensor, negatives: torch.Tensor, temperature: float
) -> torch.Tensor:
    """InfoNCE of each crop's embedding ``z_i`` (B,E) against the clean-view embeddings
    ``views`` (B,E) of the batch: view i is its match, the views j with ``negatives[i, j]``
    (B,B) bool are the alternatives (others, e.g. views of nearly the same orientation, are
    left out). Rows without a negative count as 0. This is the codebook look-up itself, trained
    directly: the crop must be closer to its own view than to the other orientations'.
    """
    rows = negatives.any(dim=1)
    if not bool(rows.any()):
        return z.sum() * 0.0
    logits = F.normalize(z, dim=1) @ F.normalize(views, dim=1).T / temperature
    eye = torch.eye(len(z), dtype=torch.bool, device=z.device)
    logits = logits.masked_fill(~(negatives | eye), float("-inf"))
    target = torch.arange(len(z), device=z.device)
    return F.cross_entropy(logits[rows], target[rows])


def far_pairs(
    R: np.ndarray, keep: np.ndarray, min_angle_deg: float, sym_d: list, sym_c: list[dict]
) -> np.ndarray:
    """(B,B) bool: rows and columns in ``keep`` (B,) whose rotations ``R`` (B,3,3) are more
    than ``min_angle_deg`` apart up to the object's symmetries."""
    b = R.shape[0]
    Ri = np.repeat(R, b, axis=0)
    Rj = np.tile(R, (b, 1, 1))
    angle = np.degrees(symmetry_aware_angle(Ri, Rj, sym_d, sym_c)).reshape(b, b)
    return (angle > min_angle_deg) & keep[:, None] & keep[None, :]


def jitter_colors(x: torch.Tensor, amount: float) -> torch.Tensor:
    """Random per-image brightness/contrast and per-channel offset, ``x`` float in [0, 1]."""
    if amount <= 0:
        return x
    b = x.shape[0]
    gain = 1.0 + (torch.rand(b, 1, 1, 1, device=x.device) * 2 - 1) * amount
    shift = (torch.rand(b, 3, 1, 1, device=x.device) * 2 - 1) * (amount / 2)
    return (x * gain + shift).clamp_(0.0, 1.0)


WARMUP_TIME_SHARE = 0.1  # lr_schedule_by_time: the warm-up ends by this share of max_time


def _warmup_cosine(
    step: int, warmup: int, total: float, min_ratio: float, time_progress: float | None = None
) -> float:
    """Learning-rate factor: linear warm-up over ``warmup`` steps, then cosine decay to
    ``min_ratio`` at ``total`` steps or, when ``time_progress`` (share of ``max_time`` gone,
    0-1) is given, at whichever of the two limits comes first; the warm-up then also ends by
    ``WARMUP_TIME_SHARE`` of the time (a 10-minute run on a loaded CPU made 37-51 steps, fewer
    than the 100 warm-up steps, and never reached its peak rate)."""
    if warmup > 0 and step < warmup:
        warm = (step + 1) / warmup
        if time_progress is not None:
            warm = max(warm, time_progress / WARMUP_TIME_SHARE)
        if warm < 1.0:
            return warm
    progress = 0.0
    if math.isfinite(total) and total > warmup:
        progress = max(0.0, (step - warmup) / max(1.0, total - warmup))
    elif time_progress is None:
        return 1.0
    if time_progress is not None:
        progress = max(progress, time_progress)
    progress = min(1.0, progress)
    return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def time_progress(callbacks: list[Any]) -> float | None:
    """Share (0-1) of the trainer's ``max_time`` that training has used so far (its ``Timer``
    callback), or None without a ``max_time``."""
    from lightning.pytorch.callbacks import Timer

    timer = next((c for c in callbacks if isinstance(c, Timer)), None)
    if timer is None:
        return None
    left = timer.time_remaining()
    if left is None:
        return None
    used = timer.time_elapsed()
    return min(1.0, max(0.0, used / max(used + left, 1e-9)))


class _ChpfModule(pl.LightningModule):
    """Common optimiser, schedule, data checks and checkpoint metadata."""

    model_type: str = ""
    model: torch.nn.Module

    def __init__(self, init_args: Mapping[str, Any]) -> None:
        """``init_args``: the subclass's ``locals()`` at the start of its ``__init__``, saved as
        plain hyper-parameters (configs as dicts): what checkpoints and logs record."""
        super().__init__()
        skip = ("self", "__class__")
        self.save_hyperparameters({k: _plain(v) for k, v in init_args.items() if k not in skip})
        self.preprocess = Preprocess()
        self.data_info: dict[str, Any] = {}
        self._time_progress: float | None = None  # lr_schedule_by_time: share of max_time gone

    # --- data -----------------------------------------------------------------------------
    def _model_size(self) -> int:
        raise NotImplementedError

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is not None and hasattr(dm, "check_crop_size"):
            dm.check_crop_size(self._model_size())
            man = dm.manifest
            self.data_info = {
                "crop": man.get("crop"),
                "object": man.get("object"),
                "object_fingerprint": man.get("object_fingerprint"),
                "object_info": man.get("object_info"),
                "data_dir": str(dm.data_dir),
            }

    def _images(self, batch: Mapping[str, torch.Tensor], key: str) -> torch.Tensor:
        x = self.preprocess(batch[key])
        if self.hparams.get("channels_last", True):
            x = x.contiguous(memory_format=torch.channels_last)
        return x

    # --- optimisation ---------------------------------------------------------------------
    def _param_groups(self) -> list[dict[str, Any]]:
        return [{"params": [p for p in self.model.parameters() if p.requires_grad]}]

    def configure_optimizers(self) -> Any:
        hp = self.hparams
        groups = self._param_groups()
        devices = {p.device.type for g in groups for p in g["params"]}
        # Adam's fused kernel where the devices have one: on a 2-core CPU 0.6 ms a step for
        # the classifier's 1.1 M parameters, against 4.2 ms for the per-tensor loop
        fused = True if devices and devices <= {"cpu", "cuda"} else None
        opt = torch.optim.Adam(groups, lr=hp.lr, weight_decay=hp.weight_decay, fused=fused)
        total = float(self.trainer.estimated_stepping_batches) if self._trainer else math.inf
        warmup, min_ratio = int(hp.warmup_steps), float(hp.min_lr_ratio)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: _warmup_cosine(s, warmup, total, min_ratio, self._time_progress)
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    def lr_scheduler_step(self, scheduler: Any, metric: Any) -> None:
        """With ``lr_schedule_by_time``: the share of ``max_time`` gone now sets the next
        step's learning rate (rank 0's clock, broadcast, so that DDP ranks keep equal
        weights)."""
        if self.hparams.get("lr_schedule_by_time", False) and self._trainer is not None:
            p = time_progress(self.trainer.callbacks)
            self._time_progress = self.trainer.strategy.broadcast(p, src=0)
        super().lr_scheduler_step(scheduler, metric)

    # --- checkpoint metadata ----------------------------------------------------------------
    def chpf_info(self) -> dict[str, Any]:
        return {
            "model_type": self.model_type,
            "format_version": CHECKPOINT_FORMAT_VERSION,
            "model_config": to_dict(self.model.config),
            "crop": self.data_info.get("crop"),
            "object": self.data_info.get("object"),
            "object_fingerprint": self.data_info.get("object_fingerprint"),
            "object_info": self.data_info.get("object_info"),
            "data_dir": self.data_info.get("data_dir"),
            "hparams": _plain(dict(self.hparams)),
        }

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["chpf"] = self.chpf_info()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        info = checkpoint.get("chpf")
        if not isinstance(info, dict) or info.get("model_type") != self.model_type:
            got = info.get("model_type") if isinstance(info, dict) else None
            raise ConfigError(f"checkpoint is of model type '{got}', expected '{self.model_type}'")
        if not self.data_info:  # not set by setup() from a datamodule
            keys = ("crop", "object", "object_fingerprint", "object_info", "data_dir")
            self.data_info = {k: info.get(k) for k in keys}

    @torch.no_grad()
    def embed_crops(
        self,
        fn: Callable[[torch.Tensor], torch.Tensor],
        crops_u8: torch.Tensor | np.ndarray,
        batch: int = 256,
    ) -> np.ndarray:
        """``fn`` (images ``(B, 3, S, S)`` -> embeddings ``(B, E)``) over uint8 crops
        ``(N, S, S, 3)`` in batches, in eval mode -> float32 ``(N, E)`` (also for N = 0)."""
        crops = torch.as_tensor(np.asarray(crops_u8))
        was_training = self.model.training
        self.model.eval()
        out = []
        for i in range(0, max(crops.shape[0], 1), batch):  # N = 0: one empty batch
            x = self._images({"x": crops[i : i + batch].to(self.device)}, "x")
            out.append(fn(x).float().cpu())
        self.model.train(was_training)
        return torch.cat(out).numpy()

    def _gather_cat(self, chunks: list[torch.Tensor]) -> np.ndarray:
        """Concatenate per-step tensors and gather them from all ranks (numpy), rank order.

        Ranks may hold different numbers of rows (empty crops are left out of retrieval, the
        last validation batch is short, a rank may have none): the shapes are exchanged first,
        each rank pads to the longest, and the padding is cut off after the gather."""
        x = torch.cat(chunks) if chunks else None
        if self._trainer is None or self.trainer.world_size <= 1:
            return (x if x is not None else torch.zeros(0)).detach().cpu().numpy()
        import torch.distributed as dist

        shapes: list[Any] = [None] * self.trainer.world_size
        mine = None if x is None else (tuple(x.shape), str(x.dtype).removeprefix("torch."))
        dist.all_gather_object(shapes, mine)
        known = [s for s in shapes if s is not None]
        if not known:
            return np.zeros(0, np.float32)
        tail, dtype = known[0][0][1:], getattr(torch, known[0][1])
        longest = max(s[0][0] for s in known)
        pad = torch.zeros((longest, *tail), dtype=dtype, device=self.device)
        if x is not None:
            pad[: x.shape[0]] = x.detach().to(self.device)
        gathered = self.all_gather(pad)  # (world, longest, ...)
        rows = [gathered[r, : s[0][0]] for r, s in enumerate(shapes) if s is not None]
        return torch.cat(rows).detach().cpu().numpy()


def _fp32(*tensors: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The tensors in float32: under ``trainer.precision: bf16-mixed`` the networks' outputs
    are bfloat16; losses, cosines and validation metrics are computed in float32."""
    return tuple(t.float() for t in tensors)


def _plain(obj: Any) -> Any:
    """Hyper-parameters as plain JSON-like Python (dicts, lists, numbers, strings)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_dict(obj)
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)


# ----------------------------------------------------------------------------- validation codebook


def load_codebook_npz(path: str | os.PathLike, size: int | None = None) -> dict[str, np.ndarray]:
    """Arrays of a codebook npz (see ``training.codebook``); DatasetError if bad, ConfigError
    if its crops are not ``size`` pixels (when given)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: codebook not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            cb = {k: z[k] for k in z.files}
    except Exception as err:
        raise DatasetError(f"{path}: unreadable codebook ({type(err).__name__})") from None
    for k in ("rotations", "crops"):
        if k not in cb:
            raise DatasetError(f"{path}: codebook lacks array '{k}'")
    if cb["crops"].ndim != 4 or cb["crops"].shape[0] != cb["rotations"].shape[0]:
        raise DatasetError(f"{path}: crops {cb['crops'].shape} do not match rotations")
    if size is not None and cb["crops"].shape[1] != size:
        raise ConfigError(
            f"{path}: codebook crop size {cb['crops'].shape[1]} differs from the model "
            f"config's size {size}"
        )
    return cb


def manifest_symmetries(object_info: Mapping[str, Any] | None) -> tuple[list, list[dict]]:
    """(discrete 4x4 list, continuous list of dicts) from a manifest's ``object_info``."""
    if not object_info:
        return [], []
    disc = [np.asarray(T, dtype=np.float64) for T in object_info.get("symmetries_discrete", [])]
    cont = [dict(c) for c in object_info.get("symmetries_continuous", [])]
    return disc, cont


def warn_if_shifted_val_crops(dm: Any) -> None:
    """Warn when the validation crops of an autoencoder's retrieval error are cut with crop
    jitter that their targets follow: the error then measures the shift (about 110 deg on the
    duck's default data, where crops without jitter read 13 deg), and best-*.ckpt follows it."""
    folder = dm.val_dir if dm.val_dir is not None else dm.data_dir
    manifest = dm.val_reader.manifest if dm.val_dir is not None else dm.manifest
    if shifts_ae_targets(manifest.get("config") or {}):
        warnings.warn(
            f"{folder}: the validation crops are cut with crop jitter that their targets follow, "
            "so val/retrieval_median_deg (which picks best-*.ckpt) measures the shift, not the "
            "orientation; give --data.val_dir an ae set made with --set crop_jitter.xy_sigma=0 "
            "--set crop_jitter.z_sigma=0 (chpf-make-bundle does)",
            stacklevel=2,
        )


def val_codebook_cache(
    root: str | os.PathLike, manifest: Mapping[str, Any], k: int
) -> tuple[Path, str]:
    """(path, key) of the cached validation codebook of ``k`` entries for a data folder's
    ``manifest`` under the run folder ``root``; the key hashes the object's fingerprint, the
    crop spec and ``k``."""
    import hashlib
    import json

    parts = {
        "object_fingerprint": manifest.get("object_fingerprint"),
        "crop": manifest.get("crop"),
        "k": int(k),
    }
    key = hashlib.sha1(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:16]
    return Path(root) / "val_codebook" / f"k{int(k)}_{key}.npz", key


def ensure_val_codebook(
    path: str | os.PathLike, key: str, data_dir: str | os.PathLike, k: int
) -> bool:
    """Render ``training.codebook.render_eval_codebook(data_dir, k)`` into ``path`` unless a
    codebook with this ``key`` is there already; a file with another key (or unreadable) is
    rebuilt. True when it rendered."""
    from training.codebook import render_eval_codebook, save_codebook

    path = Path(path)
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                if "cache_key" in z.files and str(z["cache_key"].reshape(-1)[0]) == key:
                    return False
        except Exception:
            pass
        warnings.warn(f"{path}: validation codebook of other settings: rebuilt", stacklevel=2)
    arrays = render_eval_codebook(data_dir, int(k), progress=False)
    arrays["cache_key"] = np.asarray(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_codebook(path, arrays)
    return True


# ----------------------------------------------------------------------------- autoencoder


class AELitModule(_ChpfModule):
    """Augmented autoencoder: reconstruct the clean crop from the augmented one.

    Args:
        encoder: the encoder (``training.model_config.EncoderConfig``); the decoder mirrors it
            unless ``decoder_channels`` is set.
        lr: Adam learning rate (peak, after warm-up).
        weight_decay: Adam weight decay.
        bootstrap_ratio: share of the worst pixels averaged by the bootstrapped L2 loss.
        warmup_steps: linear warm-up steps; then cosine decay to ``lr * min_lr_ratio``.
        min_lr_ratio: final learning rate as a fraction of ``lr``.
        lr_schedule_by_time: the cosine decay ends at ``trainer.max_time`` when that comes
            before ``max_steps`` (progress = the larger of the steps' and the time's share), so
            that a run stopped by ``max_time`` still ends at ``lr * min_lr_ratio``; off, the
            schedule follows steps only (same seed, same bytes when ``max_steps`` stops it).
        input_jitter: extra colour jitter on the (already augmented) inputs, 0 = off.
        channels_last: channels_last memory format (faster convolutions on CPU).
        val_codebook: npz from ``python -m training.codebook`` (rotations + clean crops); the
            validation retrieval error is measured against it.
        val_codebook_size: without ``val_codebook``: entries of a codebook of uniform
            orientations rendered from the data's object and crop spec (``training.codebook``)
            and cached as ``{trainer.default_root_dir}/val_codebook/k{K}_{key}.npz``, the key
            made of the object's fingerprint, the crop spec and K (a cache whose contents do
            not match its key is rebuilt); rank 0 renders under DDP. 0: the clean targets of
            the validation set serve as the codebook -- each crop then finds its own target,
            so the figure is optimistic (near 0) and says little.
        val_codebook_batch: crops per forward pass when embedding the codebook.
        empty_weight: weight of ``empty_separation`` in the loss (0 = off); it keeps the
            embeddings of empty crops (``chpf-gen-data`` ``empty_crops``) away from every view.
        empty_margin: cosine below which an empty crop and a view count as separated.
        view_weight: weight of ``view_separation`` in the loss (0 = off): a crop's embedding
            against the clean views of the batch's other orientations.
        view_margin: cosine below which a crop and a far view count as separated.
        view_min_angle_deg: orientations more than this apart (up to symmetry) count as far.
        match_weight: weight of ``view_matching`` in the loss (0 = off): each crop against its
            own clean view and the batch's views of other orientations (InfoNCE).
        match_temperature: softmax temperature of ``view_matching``.
        match_min_angle_deg: views closer than this to the crop's orientation are no negatives.
    """

    model_type = "ae"

    def __init__(
        self,
        encoder: EncoderConfig = DEFAULT_ENCODER,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        bootstrap_ratio: float = 0.25,
        warmup_steps: int = 100,
        min_lr_ratio: float = 0.02,
        lr_schedule_by_time: bool = False,
        input_jitter: float = 0.0,
        channels_last: bool = True,
        val_codebook: str | None = None,
        val_codebook_size: int = 4096,
        val_codebook_batch: int = 256,
        empty_weight: float = 1.0,
        empty_margin: float = 0.3,
        view_weight: float = 1.0,
        view_margin: float = 0.5,
        view_min_angle_deg: float = 90.0,
        match_weight: float = 0.0,
        match_temperature: float = 0.1,
        match_min_angle_deg: float = 20.0,
    ) -> None:
        super().__init__(locals())
        if not 0.0 < bootstrap_ratio <= 1.0:
            raise ConfigError(f"bootstrap_ratio must be in (0, 1], got {bootstrap_ratio}")
        if val_codebook_size < 0:
            raise ConfigError(f"val_codebook_size must be >= 0, got {val_codebook_size}")
        self.model = Autoencoder(encoder)
        if channels_last:
            self.model.to(memory_format=torch.channels_last)
        self._val_cb: dict[str, np.ndarray] | None = None
        self._cb_emb: np.ndarray | None = None
        self._val_outputs: dict[str, list[torch.Tensor]] = {}

    def _model_size(self) -> int:
        return self.model.config.size

    def setup(self, stage: str) -> None:
        super().setup(stage)
        if self._val_cb is not None:
            return
        if self.hparams.val_codebook:
            self._val_cb = load_codebook_npz(self.hparams.val_codebook, self._model_size())
            return
        k = int(self.hparams.get("val_codebook_size", 0) or 0)
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if k > 0 and dm is not None and stage in ("fit", "validate"):
            self._val_cb = self._rendered_codebook(dm, k)
        if self._val_cb is not None and dm is not None and hasattr(dm, "manifest"):
            warn_if_shifted_val_crops(dm)

    def _rendered_codebook(self, dm: Any, k: int) -> dict[str, np.ndarray]:
        """The cached uniform validation codebook of ``val_codebook_size`` (see the class
        docstring): rank 0 renders it when missing or stale, the other ranks wait and load."""
        path, key = val_codebook_cache(self.trainer.default_root_dir, dm.manifest, k)
        failed = None
        if self.trainer.is_global_zero:
            try:
                ensure_val_codebook(path, key, dm.data_dir, k)
            except ChpfError as err:  # told to every rank: none waits for a codebook forever
                failed = str(err)
        failed = self.trainer.strategy.broadcast(failed, src=0)
        if failed:
            raise DatasetError(
                f"{failed} (rendering the validation codebook: give --model.val_codebook FILE "
                "from python -m training.codebook --object MESH, or --model.val_codebook_size 0)"
            )
        return load_codebook_npz(path, self._model_size())

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model(x)

    def _encode(self, x: torch.Tensor) -> torch.Tensor:
        """Raw embeddings ``(B, E)`` float32 of images ``(B, 3, S, S)`` (see ``_fp32``)."""
        return self.model.encoder(x).float()

    def training_step(self, batch: Mapping[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        x = jitter_colors(self._images(batch, "input_rgb"), float(self.hparams.input_jitter))
        target = self._images(batch, "target_rgb")
        recon, z = _fp32(*self.model(x))
        loss = bootstrapped_l2(
            recon, self.model.recon_target(target), float(self.hparams.bootstrap_ratio)
        )
        hp = self.hparams
        empty = batch["visib_fract"] <= 0 if "visib_fract" in batch else None
        views = None  # clean views: the codebook's kind of crop (black around)
        if (hp.view_weight > 0 or hp.match_weight > 0) and "R_allo" in batch:
            with torch.no_grad():
                views = self._encode(target)
            keep = np.ones(len(z), bool) if empty is None else (~empty).cpu().numpy()
            R = batch["R_allo"].detach().cpu().double().numpy()
            sym = manifest_symmetries(self.data_info.get("object_info"))

            def apart(min_deg: float) -> torch.Tensor:
                return torch.from_numpy(far_pairs(R, keep, min_deg, *sym)).to(z.device)

            if hp.view_weight > 0:
                sep = view_separation(z, views, apart(hp.view_min_angle_deg), hp.view_margin)
                self.log("train/view_sep", sep)
                loss = loss + float(hp.view_weight) * sep
            if hp.match_weight > 0:
                negatives = apart(hp.match_min_angle_deg)
                match = view_matching(z, views, negatives, float(hp.match_temperature))
                self.log("train/view_match", match)
                loss = loss + float(hp.match_weight) * match
        if hp.empty_weight > 0 and empty is not None:
            empty_views = None
            if bool(empty.any()):
                if views is None:
                    with torch.no_grad():
                        views = self._encode(target[~empty][:16])
                    empty_views = views
                else:
                    empty_views = views[~empty][:16]
            sep = empty_separation(z, empty, float(hp.empty_margin), empty_views)
            self.log("train/empty_sep", sep)
            loss = loss + float(hp.empty_weight) * sep
        self.log("train/loss", loss, prog_bar=True)
        return loss

    # --- validation -------------------------------------------------------------------------
    def embed(self, crops_u8: torch.Tensor | np.ndarray, batch: int = 256) -> np.ndarray:
        """L2-normalised embeddings ``(N, E)`` of uint8 crops ``(N, S, S, 3)``."""
        return self.embed_crops(lambda x: F.normalize(self._encode(x), dim=1), crops_u8, batch)

    def on_validation_epoch_start(self) -> None:
        self._val_outputs = {"z": [], "R": [], "tz": []}
        self._cb_emb = None
        if self._val_cb is not None:
            self._cb_emb = self.embed(self._val_cb["crops"], int(self.hparams.val_codebook_batch))

    def validation_step(self, batch: Mapping[str, torch.Tensor], batch_idx: int) -> None:
        x = self._images(batch, "input_rgb")
        target = self._images(batch, "target_rgb")
        recon, z = _fp32(*self.model(x))
        small = self.model.recon_target(target)
        loss = bootstrapped_l2(recon, small, float(self.hparams.bootstrap_ratio))
        mse = F.mse_loss(recon, small)
        bs = x.shape[0]
        self.log("val/recon_loss", loss, prog_bar=True, batch_size=bs, sync_dist=True)
        self.log("val/mse", mse, batch_size=bs, sync_dist=True)
        # retrieval is undefined for empty crops (no object: visib_fract 0)
        keep = batch["visib_fract"] > 0 if "visib_fract" in batch else slice(None)
        self._val_outputs["z"].append(F.normalize(z[keep], dim=1))
        self._val_outputs["R"].append(batch["R_allo"][keep].float())
        if self._val_cb is None:
            self._val_outputs["tz"].append(F.normalize(self._encode(target[keep]), dim=1))

    def on_validation_epoch_end(self) -> None:
        z = self._gather_cat(self._val_outputs["z"])
        R = self._gather_cat(self._val_outputs["R"]).astype(np.float64)
        if z.shape[0] == 0:
            return
        if self._val_cb is not None and self._cb_emb is not None:
            cb_emb, cb_R = self._cb_emb, self._val_cb["rotations"].astype(np.float64)
            sym_d = list(self._val_cb.get("symmetries_discrete", np.zeros((0, 4, 4))))
            axes = self._val_cb.get("symmetries_continuous_axes", np.zeros((0, 3)))
            sym_c = [{"axis": a} for a in axes]
        else:
            cb_emb, cb_R = self._gather_cat(self._val_outputs["tz"]), R
            sym_d, sym_c = manifest_symmetries(self.data_info.get("object_info"))
        idx, _ = cosine_retrieval(z, cb_emb)
        err = np.degrees(symmetry_aware_angle(cb_R[idx], R, sym_d, sym_c))
        summary = retrieval_summary(err, 30.0)
        # identical on every rank (gathered): sync_dist only silences Lightning's DDP warning
        self.log("val/retrieval_median_deg", summary["median_deg"], prog_bar=True, sync_dist=True)
        self.log("val/retrieval_pct_below30", summary["pct_below"], sync_dist=True)
        self._val_outputs = {}


# ----------------------------------------------------------------------------- classifier


class CHLitModule(_ChpfModule):
    """Counter-Hypothetical classifier: BCE on P(misaligned) (label = 1 - aligned).

    Args:
        classifier: the classifier (``training.model_config.ClassifierConfig``: encoder, head,
            share_twin, shares_ae_encoder).
        init_from_ae: autoencoder checkpoint whose encoder initialises both branches (its
            encoder config replaces ``classifier.encoder``). Recommended: from scratch the
            classifier learns slowly.
        freeze_encoder: shared-encoder mode -- the observed (and candidate) branch IS the
            autoencoder's encoder, frozen; only the head trains, so at run time one encoder
            pass per crop serves both L and C. Needs ``init_from_ae``.
        freeze_candidate: the candidate branch IS the autoencoder's encoder, frozen; only the
            observed branch and the head train. A step then back-propagates through one
            encoder pass instead of two, and the bundle's candidate embeddings are the
            autoencoder's codebook embeddings (no second codebook). Needs ``init_from_ae``.
        lr: Adam learning rate of the head (peak).
        encoder_lr_scale: encoder learning rate = ``lr * encoder_lr_scale`` (when trained).
        weight_decay, warmup_steps, min_lr_ratio, lr_schedule_by_time, channels_last: as in
            ``AELitModule``.
        input_jitter: extra colour jitter on the observed crops, 0 = off.
        augment: occluders and appearance changes drawn onto the observed crops
            (``training.batch_augment.BatchAugment``; off by default).
        hard_negative_deg: [lo, hi] angle range (degrees) of the hard negatives for val/auc_hard.
        occluded_visib: [lo, hi] visible fraction of the occluded positives for
            val/aligned_rate_occluded (share of them called aligned, p < 0.5).
        occluded_pos_weight: BCE weight of positives with visib_fract <= occluded_visib[1]
            (occlusion must not count against a pose), 1 = plain BCE.
        hard_neg_weight: BCE weight of negatives whose angle is in ``hard_negative_deg``.
        extra_pairs: hypotheses per observed crop besides its own pair (0 = off), drawn like
            the data's candidates and scored against the candidate embeddings of
            ``candidate_codebook`` (``training.extra_pairs``): many pairs per encoder pass.
            Needs ``freeze_candidate`` (exact embeddings) or ``candidate_refresh_steps``.
        candidate_refresh_steps: with a trained candidate branch, the codebook's candidate
            embeddings for the extra pairs are recomputed every this many steps (so they lag
            the branch by at most that many); the batch's own pairs go through the branch.
        candidate_codebook: npz of ``python -m training.codebook`` (grid rotations and clean
            crops of the object) for ``extra_pairs``.
        extra_pairs_mix: keys of the chpf-gen-data ``pairs`` config that the extra pairs draw
            differently from the data (e.g. ``{hard_negative_share: 0.7}``; null keys keep the
            data's values).
    """

    model_type = "ch"

    def __init__(
        self,
        classifier: ClassifierConfig = DEFAULT_CLASSIFIER,
        init_from_ae: str | None = None,
        freeze_encoder: bool = False,
        freeze_candidate: bool = False,
        lr: float = 1e-3,
        encoder_lr_scale: float = 0.3,
        weight_decay: float = 0.0,
        warmup_steps: int = 100,
        min_lr_ratio: float = 0.02,
        lr_schedule_by_time: bool = False,
        input_jitter: float = 0.0,
        channels_last: bool = True,
        hard_negative_deg: tuple[float, float] = (20.0, 45.0),
        occluded_visib: tuple[float, float] = (0.3, 0.6),
        occluded_pos_weight: float = 1.0,
        hard_neg_weight: float = 1.0,
        extra_pairs: int = 0,
        candidate_codebook: str | None = None,
        extra_pairs_mix: PairsMix = NO_MIX,
        candidate_refresh_steps: int = 0,
        augment: BatchAugment = NO_AUGMENT,
    ) -> None:
        super().__init__(locals())
        if occluded_pos_weight <= 0 or hard_neg_weight <= 0:
            raise ConfigError("occluded_pos_weight and hard_neg_weight must be > 0")
        if extra_pairs < 0:
            raise ConfigError(f"extra_pairs must be >= 0, got {extra_pairs}")
        if candidate_refresh_steps < 0:
            raise ConfigError(
                f"candidate_refresh_steps must be >= 0, got {candidate_refresh_steps}"
            )
        if candidate_refresh_steps and (freeze_candidate or freeze_encoder):
            raise ConfigError("candidate_refresh_steps is for a trained candidate branch")
        if extra_pairs and not (
            (freeze_candidate or candidate_refresh_steps) and candidate_codebook
        ):
            raise ConfigError(
                "extra_pairs needs a candidate_codebook and freeze_candidate or "
                "candidate_refresh_steps"
            )
        self.extra_pairs_mix = extra_pairs_mix
        self.augment = augment
        self._augment_rng = np.random.default_rng(0)
        cfg = classifier
        self.ae_info: dict[str, Any] | None = None
        for key, on in (("freeze_encoder", freeze_encoder), ("freeze_candidate", freeze_candidate)):
            if on and not init_from_ae:
                raise ConfigError(f"{key} needs init_from_ae (an autoencoder checkpoint)")
        if freeze_encoder and freeze_candidate:
            raise ConfigError("freeze_encoder already freezes both branches: drop freeze_candidate")
        if init_from_ae:
            self.ae_info = checkpoint_info(init_from_ae, expect="ae")
            ae_encoder = from_stored(EncoderConfig, self.ae_info["model_config"], init_from_ae)
            cfg = dataclasses.replace(cfg, encoder=ae_encoder)
        if freeze_encoder:
            cfg = dataclasses.replace(cfg, share_twin=True, shares_ae_encoder=True)
        if freeze_candidate:
            cfg = dataclasses.replace(cfg, share_twin=False)
        self.model = CHClassifier(cfg)
        self._candidates: CandidateCodebook | None = None
        self._data_pairs_cfg: dict[str, Any] = {}  # the data's pairs config (on_train_start)
        self._candidate_crops: np.ndarray | None = None
        self._candidates_embedded_at = -1  # global step of the last codebook embedding
        self._pair_rng = np.random.default_rng(0)
        frozen = self._frozen_branch()
        if frozen is not None:
            frozen.requires_grad_(False)
        if channels_last:
            self.model.to(memory_format=torch.channels_last)
        self.ae_encoder_sha256: str | None = None
        self._ae_loaded = False
        self._val_outputs: dict[str, list[torch.Tensor]] = {}

    def _model_size(self) -> int:
        return self.model.config.encoder.size

    def setup(self, stage: str) -> None:
        super().setup(stage)
        resuming = self._trainer is not None and self.trainer.ckpt_path is not None
        if self.hparams.init_from_ae and not self._ae_loaded and not resuming:
            self.init_encoders_from_ae(self.hparams.init_from_ae)

    def init_encoders_from_ae(self, path: str | os.PathLike) -> None:
        """Copy an AE checkpoint's encoder weights into both branches (ConfigError if not 'ae')."""
        ae, info = load_autoencoder(path)
        branches = (self.model.obs_encoder, self.model.cand_encoder)
        for encoder in {id(e): e for e in branches}.values():
            missing, unexpected = encoder.load_state_dict(ae.encoder.state_dict(), strict=False)
            if unexpected or any(not k.startswith("refine.") for k in missing):
                raise ConfigError(f"{path}: its encoder does not fit the classifier's")
        if self.hparams.channels_last:
            self.model.to(memory_format=torch.channels_last)
        self.ae_encoder_sha256 = state_sha256(ae.encoder)
        ae_crop = info.get("crop")
        if ae_crop and self.data_info.get("crop") and ae_crop != self.data_info["crop"]:
            warnings.warn(
                f"{path}: autoencoder was trained on crops {ae_crop}, the pairs use "
                f"{self.data_info['crop']}",
                stacklevel=2,
            )
        self._ae_loaded = True

    def _frozen_branch(self) -> torch.nn.Module | None:
        """The branch that is the autoencoder's frozen encoder, if any."""
        if self.hparams.get("freeze_encoder", False):
            return self.model.obs_encoder
        if self.hparams.get("freeze_candidate", False):
            return self.model.cand_encoder
        return None

    def train(self, mode: bool = True) -> CHLitModule:
        super().train(mode)
        frozen = self._frozen_branch()
        if frozen is not None:
            frozen.eval()
        return self

    def _param_groups(self) -> list[dict[str, Any]]:
        head = list(self.model.head.parameters())
        enc_params = {id(p): p for p in self.model.obs_encoder.parameters()}
        enc_params.update({id(p): p for p in self.model.cand_encoder.parameters()})
        enc = [p for p in enc_params.values() if p.requires_grad]
        groups: list[dict[str, Any]] = [{"params": head}]
        if enc:
            scale = float(self.hparams.encoder_lr_scale)
            groups.append({"params": enc, "lr": float(self.hparams.lr) * scale})
        return groups

    def forward(self, obs: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return self.model(obs, cand)

    def _step(self, batch: Mapping[str, torch.Tensor], train: bool) -> tuple[torch.Tensor, ...]:
        obs = self._images(batch, "obs_rgb")
        if train:
            obs = jitter_colors(obs, float(self.hparams.input_jitter))
            obs = augment_batch(obs, self.augment, self._augment_rng)
        y = 1.0 - batch["aligned"].float()
        if train and self._candidates is not None and self.hparams.freeze_candidate:
            # the frozen candidate views' embeddings are known exactly
            obs_n = self.model.embed_obs(obs)
            cand_n = self._candidates.embed(batch["cand_R_allo"].cpu().numpy()).to(obs_n)
        else:
            obs_n, cand_n = self.model.embed_pair(obs, self._images(batch, "cand_rgb"))
        logit = self.model.head(obs_n, cand_n).float()
        visib, angle = batch["visib_fract"].float(), batch["angle_deg"].float()
        if not train:
            return F.binary_cross_entropy_with_logits(logit, y), logit, y
        logits, labels = logit, y
        if self._candidates is not None:
            m = int(self.hparams.extra_pairs)
            idx, y_x, ang_x = self._candidates.draw(
                batch["obs_R_allo"].detach().cpu().double().numpy(),
                (visib > 0).cpu().numpy(),
                m,
                self._pair_rng,
                depth_off(batch["depth_ratio"].cpu().numpy(), self._data_pairs_cfg),
            )
            cand_x = self._candidates.embeddings[torch.from_numpy(idx.reshape(-1))]
            logit_x = self.model.head(obs_n.repeat_interleave(m, 0), cand_x.to(obs_n)).float()
            logits = torch.cat([logit, logit_x])
            labels = torch.cat([y, torch.from_numpy(y_x.reshape(-1)).to(y)])
            visib = torch.cat([visib, visib.repeat_interleave(m)])
            angle = torch.cat([angle, torch.from_numpy(ang_x.reshape(-1)).to(angle)])
        weight = self._pair_weights(labels, visib, angle)
        loss = F.binary_cross_entropy_with_logits(logits, labels, weight=weight)
        return loss, logit, y

    def _pair_weights(
        self, y: torch.Tensor, visib: torch.Tensor, angle: torch.Tensor
    ) -> torch.Tensor | None:
        """BCE weights (N,) of training pairs (labels y, 1 = misaligned): occluded positives
        and hard negatives weighted as configured, normalised to mean 1; None if all are 1."""
        hp = self.hparams
        if hp.occluded_pos_weight == 1.0 and hp.hard_neg_weight == 1.0:
            return None
        weight = torch.ones_like(y)
        occl = (y == 0) & (visib <= hp.occluded_visib[1])
        weight = torch.where(occl, weight * hp.occluded_pos_weight, weight)
        lo, hi = hp.hard_negative_deg
        hard = (y == 1) & (angle >= lo) & (angle <= hi)
        weight = torch.where(hard, weight * hp.hard_neg_weight, weight)
        return weight / weight.mean()

    def on_train_start(self) -> None:
        """With ``extra_pairs``: embed the candidate codebook with the (restored)
        candidate branch, and seed the draws (extra pairs, augmentation) from the run's seed
        and the rank."""
        self._augment_rng = np.random.default_rng([torch.initial_seed(), self.global_rank, 1])
        if not self.hparams.extra_pairs:
            return
        cb = load_codebook_npz(self.hparams.candidate_codebook, self._model_size())
        self._candidate_crops = cb["crops"]
        emb = self._embed_candidate_views()
        manifest = self.trainer.datamodule.manifest
        data_cfg = manifest.get("config", {})
        k_data = data_cfg.get("codebook", {}).get("size")
        if k_data is not None and int(k_data) != len(cb["rotations"]):
            warnings.warn(
                f"{self.hparams.candidate_codebook}: {len(cb['rotations'])} entries, the pairs "
                f"were drawn from a {k_data}-entry grid: their candidates are looked up at the "
                "nearest entry",
                stacklevel=2,
            )
        self._data_pairs_cfg = data_pairs_config(manifest)  # how its crops were cut (depth_off)
        pairs_cfg = self._data_pairs_cfg | mix_overrides(self.extra_pairs_mix)
        info = manifest.get("object_info")
        self._candidates = CandidateCodebook(cb["rotations"], emb, pairs_cfg, info)
        self._pair_rng = np.random.default_rng([torch.initial_seed(), self.global_rank])

    def _embed_candidate_views(self) -> torch.Tensor:
        """Candidate-branch embeddings (K, E) of the candidate codebook's clean views, now."""
        self._candidates_embedded_at = self.global_step
        return torch.from_numpy(self.embed_crops(self.model.embed_cand, self._candidate_crops))

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        """Re-embed the candidate codebook every ``candidate_refresh_steps`` steps (not again
        at the step ``on_train_start`` embedded it, e.g. a resumed run's first)."""
        every = int(self.hparams.get("candidate_refresh_steps", 0))
        step = self.global_step
        due = every > 0 and step % every == 0 and step != self._candidates_embedded_at
        if self._candidates is None or not due:
            return
        self._candidates.embeddings = self._embed_candidate_views()

    def training_step(self, batch: Mapping[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        loss, logit, y = self._step(batch, train=True)
        acc = ((logit > 0).float() == y).float().mean()
        self.log("train/loss", loss, prog_bar=True)
        self.log("train/acc", acc)
        return loss

    def on_validation_epoch_start(self) -> None:
        self._val_outputs = {"logit": [], "y": [], "angle": [], "visib": []}

    def validation_step(self, batch: Mapping[str, torch.Tensor], batch_idx: int) -> None:
        loss, logit, y = self._step(batch, train=False)
        self.log("val/loss", loss, prog_bar=True, batch_size=y.shape[0], sync_dist=True)
        self._val_outputs["logit"].append(logit.detach())
        self._val_outputs["y"].append(y)
        self._val_outputs["angle"].append(batch["angle_deg"].float())
        self._val_outputs["visib"].append(batch["visib_fract"].float())

    def on_validation_epoch_end(self) -> None:
        out = {k: self._gather_cat(v) for k, v in self._val_outputs.items()}
        self._val_outputs = {}
        if out["y"].size == 0:
            return
        m = classifier_metrics(
            out["logit"],
            out["y"],
            out["angle"],
            out["visib"],
            tuple(self.hparams.hard_negative_deg),
            tuple(self.hparams.occluded_visib),
        )
        self.log("val/acc", m["acc"], prog_bar=True, sync_dist=True)
        self.log("val/auc", m["auc"], prog_bar=True, sync_dist=True)
        for k in ("auc_hard", "aligned_rate_pos", "aligned_rate_occluded", "empty_rejected"):
            if not math.isnan(m[k]):
                self.log(f"val/{k}", m[k], sync_dist=True)

    def chpf_info(self) -> dict[str, Any]:
        info = super().chpf_info()
        info["shares_ae_encoder"] = bool(self.model.shares_ae_encoder)
        info["ae_encoder_sha256"] = self.ae_encoder_sha256
        info["ae_checkpoint"] = self.hparams.init_from_ae
        return info

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        super().on_load_checkpoint(checkpoint)
        self.ae_encoder_sha256 = checkpoint["chpf"].get("ae_encoder_sha256")
        self._ae_loaded = True


def pair_subsets(
    y: np.ndarray,
    angle_deg: np.ndarray,
    visib: np.ndarray,
    hard_deg: tuple[float, float] = (20.0, 45.0),
    occluded_visib: tuple[float, float] = (0.3, 0.6),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boolean masks (N,) of pairs with labels ``y`` (1 = misaligned): positives, hard negatives
    (angle in ``hard_deg``, object in the crop), positives with visib_fract in
    ``occluded_visib``, and empty crops (visib_fract 0, no object)."""
    y = np.asarray(y) > 0.5
    angle_deg, visib = np.asarray(angle_deg), np.asarray(visib)
    empty = visib <= 0
    hard = y & ~empty & (angle_deg >= hard_deg[0]) & (angle_deg <= hard_deg[1])
    occl = ~y & (visib >= occluded_visib[0]) & (visib <= occluded_visib[1])
    return ~y, hard, occl, empty


def classifier_metrics(
    logit: np.ndarray,
    y: np.ndarray,
    angle_deg: np.ndarray,
    visib: np.ndarray,
    hard_deg: tuple[float, float] = (20.0, 45.0),
    occluded_visib: tuple[float, float] = (0.3, 0.6),
) -> dict[str, float]:
    """Classifier figures from logits of P(misaligned) and labels ``y`` (1 = misaligned).

    acc (threshold p = 0.5), auc (all pairs that show the object), auc_hard (all positives vs
    negatives whose angle is in ``hard_deg``), aligned_rate_pos (positives called aligned),
    aligned_rate_occluded (positives with visib_fract in ``occluded_visib`` called aligned),
    empty_rejected (empty-crop negatives, visib_fract 0, called misaligned).
    """
    logit, y = np.asarray(logit, np.float64), np.asarray(y) > 0.5
    called_mis = logit > 0
    pos, hard, occl, empty = pair_subsets(y, angle_deg, visib, hard_deg, occluded_visib)
    sel = pos | hard
    nan = float("nan")
    return {
        "acc": float(np.mean(called_mis == y)),
        "auc": roc_auc(logit[~empty], y[~empty]),
        "auc_hard": roc_auc(logit[sel], y[sel]) if hard.any() and pos.any() else nan,
        "aligned_rate_pos": float(np.mean(~called_mis[pos])) if pos.any() else nan,
        "aligned_rate_occluded": float(np.mean(~called_mis[occl])) if occl.any() else nan,
        "empty_rejected": float(np.mean(called_mis[empty & y])) if (empty & y).any() else nan,
        "n": float(y.size),
        "n_hard": float(hard.sum()),
        "n_occluded": float(occl.sum()),
    }
