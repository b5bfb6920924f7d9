"""The export pipeline: checkpoints -> ONNX graphs + codebook -> checked bundle folder."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
from torch import nn

from chpf import __version__
from chpf.atomic import npz_bytes
from chpf.bundle import FORMAT_VERSION, ObjectInfo, check_crop_size
from chpf.crops import CropSpec
from chpf.errors import BundleError
from chpf.hashing import sha256_file
from chpf.objects import ObjectModel, object_fingerprint
from data_gen.mesh_checks import checked_object
from export import onnx_export as ox
from export.codebook import build_codebook, render_pool
from export.config import ExportConfig
from export.writer import (
    check_out,
    staging_dir,
    to_jsonable,
    write_files,
    write_manifest,
)
from export.writer import install as install_dir
from training.checkpoints import load_autoencoder, load_classifier
from training.models import Autoencoder, CHClassifier, Encoder

AE_FILE = "ae_encoder.onnx"
CH_FILE = "ch_encoder.onnx"
HEAD_FILE = "ch_head.onnx"
CODEBOOK_FILE = "codebook.npz"

PoolFn = Callable[..., tuple[Any, Any]]  # (obj, spec, k, cache_dir, workers, progress)


def same_weights(a: nn.Module, b: nn.Module) -> bool:
    """True if two modules are the same object or hold identical parameters and buffers."""
    if a is b:
        return True
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(
        sa[k].shape == sb[k].shape and torch.equal(sa[k], sb[k]) for k in sa
    )


@dataclass
class Graph:
    """One exported branch: torch module (runtime graph), ONNX bytes and an ORT session."""

    module: nn.Module
    onnx: bytes
    session: ort.InferenceSession

    def embed(self, crops: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"crops": crops})[0]


@dataclass
class ExportResult:
    """What ``export_bundle`` did: the bundle folder, its manifest and the parity errors."""

    out: Path
    manifest: dict[str, Any]
    parity: dict[str, float] = field(default_factory=dict)


def _encoder_graph(encoder: Encoder, threads: int) -> Graph:
    data = ox.export_encoder(encoder)
    return Graph(ox.embedder_module(encoder), data, ox.make_session(data, threads))


def resolve_spec(
    obj: ObjectModel, ae_info: dict[str, Any], ch_info: dict[str, Any], size: int, where: str
) -> CropSpec:
    """Crop spec recorded in the checkpoints (must agree), else ``CropSpec.for_object``."""
    specs = {}
    for kind, info in (("ae", ae_info), ("ch", ch_info)):
        if info.get("crop"):
            specs[kind] = CropSpec.from_dict(info["crop"])
    if len(specs) == 2 and specs["ae"] != specs["ch"]:
        raise BundleError(
            f"{where}: the checkpoints were trained with different crop specs "
            f"({specs['ae'].to_dict()} vs {specs['ch'].to_dict()})"
        )
    spec = next(iter(specs.values()), None) or CropSpec.for_object(obj.diameter, size=size)
    if spec.size != size:
        raise BundleError(f"{where}: crop size {spec.size} != encoder input size {size}")
    return spec


def _check_models(
    ae: Autoencoder, ch: CHClassifier, ae_info: dict, ch_info: dict, obj: ObjectModel, where: str
) -> None:
    fingerprint = object_fingerprint(obj)
    for kind, info in (("AE", ae_info), ("CH", ch_info)):
        trained_on = info.get("object")
        if trained_on and trained_on != obj.name:
            raise BundleError(
                f"{where}: the {kind} checkpoint was trained on object '{trained_on}', "
                f"not '{obj.name}'"
            )
        trained_fp = info.get("object_fingerprint")
        if trained_fp and trained_fp != fingerprint:
            warnings.warn(
                f"{where}: the {kind} checkpoint was trained on another version of the mesh "
                f"of '{obj.name}' (fingerprint {trained_fp[:10]} != {fingerprint[:10]})",
                stacklevel=3,
            )
    a, c = ae.encoder, ch.obs_encoder
    if (a.size, a.embedding_dim) != (c.size, c.embedding_dim):
        raise BundleError(
            f"{where}: AE encoder (size {a.size}, E {a.embedding_dim}) and CH encoder "
            f"(size {c.size}, E {c.embedding_dim}) disagree"
        )
    if ch.shares_ae_encoder and not same_weights(c, a):
        raise BundleError(
            f"{where}: the CH checkpoint shares the AE encoder but its encoder weights differ "
            "from the given AE checkpoint (trained from another autoencoder)"
        )


def export_bundle(
    ae_ckpt: str | os.PathLike,
    ch_ckpt: str | os.PathLike,
    obj: str | ObjectModel,
    out: str | os.PathLike,
    config: ExportConfig | None = None,
    overwrite: bool = False,
    progress: bool = True,
    pool_fn: PoolFn = render_pool,
    allow_size: bool = False,
) -> ExportResult:
    """Export the two checkpoints and a codebook for ``obj`` into the bundle folder ``out``.

    ``obj`` is a built-in name, a mesh path or an ObjectModel. Raises MeshError (also for a mesh
    whose diameter is outside 1 cm - 2 m, unless ``allow_size``), ConfigError (bad or wrong type
    of checkpoint) or BundleError (inconsistent models, parity failure, OUT holds another
    object), all before any rendering; in every error case nothing is written.
    """
    cfg = config or ExportConfig()
    out = Path(out)
    ae_path, ch_path = Path(ae_ckpt), Path(ch_ckpt)
    where = f"{ae_path.name} + {ch_path.name}"
    model = (
        obj
        if isinstance(obj, ObjectModel)
        else checked_object(str(obj), unit=cfg.unit, allow_size=allow_size)
    )
    if cfg.obj_id is not None:
        model = replace(model, obj_id=int(cfg.obj_id))
    check_out(out, model.name, overwrite)
    ae, ae_info = load_autoencoder(ae_path)
    ch, ch_info = load_classifier(ch_path)
    _check_models(ae, ch, ae_info, ch_info, model, where)
    size = ae.encoder.size
    spec = resolve_spec(model, ae_info, ch_info, size, where)
    check_crop_size(spec.size, where)
    shared = ch.shares_ae_encoder or same_weights(ch.obs_encoder, ae.encoder)
    threads = cfg.threads

    # ONNX graphs (in memory) and their sessions
    with torch.no_grad():
        ae_g = _encoder_graph(ae.encoder, threads)
        obs_g = ae_g if shared else _encoder_graph(ch.obs_encoder, threads)
        if same_weights(ch.cand_encoder, ch.obs_encoder):
            cand_g = obs_g
        elif same_weights(ch.cand_encoder, ae.encoder):
            cand_g = ae_g
        else:
            cand_g = _encoder_graph(ch.cand_encoder, threads)
        head_bytes = ox.export_head(ch.head)
        head_g = Graph(ox.head_module(ch.head), head_bytes, ox.make_session(head_bytes, threads))

    # rendered views (cached pool), parity on real crops, codebook
    k = int(cfg.codebook_size)
    grid, views = pool_fn(model, spec, k, cfg.cache_dir, cfg.workers, progress)
    if len(grid) != k or views.rgb.shape != (k, spec.size, spec.size, 3):
        raise BundleError(
            f"render pool for '{model.name}': got {len(grid)} views of shape "
            f"{views.rgb.shape[1:]}, expected {k} of ({spec.size}, {spec.size}, 3)"
        )
    pick = np.unique(np.linspace(0, k - 1, min(cfg.parity_samples, k)).astype(np.int64))
    crops = np.ascontiguousarray(views.rgb[pick])
    parity: dict[str, float] = {}
    tol = float(cfg.parity_tol)
    checked: list[Graph] = []
    for name, g in (("ae_encoder", ae_g), ("ch_encoder", obs_g), ("ch_cand_encoder", cand_g)):
        if not any(g is h for h in checked):  # each distinct graph once
            checked.append(g)
            parity[name] = ox.check_parity(name, g.session, g.module, {"crops": crops}, tol)

    book = build_codebook(
        grid,
        views.rgb,
        views.depth,
        ae_g.embed,
        None if cand_g is ae_g else cand_g.embed,
        depth_factor=int(cfg.depth_factor),
        batch=int(cfg.embed_batch),
        progress=progress,
    )
    obs = obs_g.embed(crops)
    rng = np.random.default_rng(0)
    cand_idx = np.where(np.arange(len(pick)) % 2 == 0, pick, rng.integers(0, k, len(pick)))
    head_in = {"obs": obs, "cand": np.ascontiguousarray(book.ch_embeddings[cand_idx])}
    parity["ch_head"] = ox.check_parity("ch_head", head_g.session, head_g.module, head_in, tol)

    # files, manifest, atomic install
    files = {AE_FILE: ae_g.onnx, HEAD_FILE: head_g.onnx}
    if not shared:
        files[CH_FILE] = obs_g.onnx
    files[CODEBOOK_FILE] = npz_bytes(book.arrays(), compressed=True)
    info = ObjectInfo(
        name=model.name,
        obj_id=int(model.obj_id),
        diameter=float(model.diameter),
        symmetries_discrete=np.asarray(model.symmetries_discrete, np.float64).reshape(-1, 4, 4),
        symmetries_continuous=[
            {"axis": np.asarray(s["axis"], float), "offset": np.asarray(s.get("offset", (0, 0, 0)))}
            for s in model.symmetries_continuous
        ],
        fingerprint=model.file_fingerprint or object_fingerprint(model),
        file_offset=np.asarray(model.file_offset, np.float64),
    )
    training = {
        kind: {"checkpoint": p.name, "checkpoint_sha256": sha256_file(p), **inf}
        for kind, p, inf in (("ae", ae_path, ae_info), ("ch", ch_path, ch_info))
    }
    with staging_dir(out) as tmp:
        hashes = write_files(tmp, files)
        manifest = {
            "format_version": FORMAT_VERSION,
            "object": info.to_dict(),
            "crop": spec.to_dict(),
            "embedding_dim": int(book.ae_embeddings.shape[1]),
            "codebook_size": k,
            "ch_shares_ae_encoder": bool(shared),
            "files": {
                "ae_encoder": AE_FILE,
                "ch_obs_encoder": None if shared else CH_FILE,
                "ch_head": HEAD_FILE,
                "codebook": CODEBOOK_FILE,
            },
            "sha256": hashes,
            "codebook": {
                "grid": "chpf.geometry.RotationGrid.uniform",
                "depth_size": int(book.depth.shape[1]),
                "depth_reduction": f"{cfg.depth_factor}x{cfg.depth_factor} mean of valid pixels, "
                "0 if fewer than half valid",
            },
            "parity": {"max_abs_diff": parity, "tolerance": tol, "crops": len(pick)},
            "onnx": {"opset": ox.OPSET, "exporter": f"torch {torch.__version__} (TorchScript)"},
            "training": training,
            "export": cfg.to_dict(),
            "created_by": f"chpf-export {__version__}",
        }
        manifest = to_jsonable(manifest)
        write_manifest(tmp, manifest)
        check_out(out, model.name, overwrite)
        install_dir(tmp, out)
    return ExportResult(out=out, manifest=manifest, parity=parity)
