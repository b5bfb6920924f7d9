"""int8 encoders for a model bundle: onnxruntime's static quantisation in QDQ format (int8
weights per output channel in the 7-bit range, uint8 activations), calibrated on real crops and
checked against the float32 encoders before anything is written.

Calibration crops are cut from a BOP dataset with ground truth (by default the shipped demo
sequence when it shows the bundle's object) at the true translation jittered the way a
tracker's particles are (a few centimetres, +-10 % in depth): the activations the int8 model
must cover are those of the crops the filter embeds. Half of them calibrate, the other half
measure the agreement: the cosine between each crop's int8 and float32 embedding. Below
``min_cosine`` (0.99 by default) nothing is written.

The int8 files (``ae_encoder.int8.onnx``, ``ch_encoder.int8.onnx``) go next to the float32
ones; the manifest's ``precisions.int8`` records them, the calibration and the agreement, and
``sha256`` their hashes, so ``Bundle.load(path, precision="int8")`` and ``chpf-track --set
runtime.precision=int8`` use them.
"""

from __future__ import annotations

import json
import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chpf.atomic import atomic_write_bytes
from chpf.bop import BopDataset
from chpf.bundle import MANIFEST, PRECISION_FILES, Bundle, sha256_file
from chpf.crops import crop_affines, extract_crops
from chpf.errors import BundleError
from export.qdq_input import fold_input_chain
from export.writer import write_manifest

INT8_SUFFIX = ".int8.onnx"


@dataclass
class QuantizeReport:
    """What ``quantize_bundle`` wrote and measured: files (key -> file name), min_cosine (key ->
    the lowest int8-vs-float32 cosine on the held-out crops), crops (calibration, held out)."""

    files: dict[str, str]
    min_cosine: dict[str, float]
    crops: tuple[int, int]


def calibration_crops(
    dataset: str | Path, bundle: Bundle, n: int = 512, seed: int = 0, obj_id: int | None = None
) -> np.ndarray:
    """n uint8 crops (n,S,S,3) of the bundle's object in ``dataset`` (test split, every scene)
    at its true translation jittered like a particle (0.1 diameter sideways, 10 % in depth).
    ``obj_id``: the dataset's id of that object (default: the bundle's own)."""
    ds = BopDataset(dataset)
    own = obj_id is None
    obj_id = bundle.obj_info.obj_id if own else obj_id
    frames = []
    for sid in ds.scene_ids("test"):
        scene = ds.scene("test", sid)
        for im in scene.image_ids():
            pose = next((p for p in scene.gt.get(im, []) if p.obj_id == obj_id), None)
            if pose is not None:
                frames.append((scene, im, np.asarray(pose.t, dtype=np.float64)))
    if not frames:
        hint = " (the bundle's own id; --obj-id N names the dataset's)" if own else ""
        raise BundleError(
            f"{dataset}: no ground-truth pose of obj_id {obj_id} to cut crops at{hint}"
        )
    rng = np.random.default_rng(seed)
    per_frame = -(-n // len(frames))
    d = bundle.obj_info.diameter
    crops = []
    for scene, im, t in frames:
        jitter = rng.normal(0.0, 0.1 * d, (per_frame, 3))
        ts = t[None] + jitter * np.array([1.0, 1.0, 0.0])
        ts[:, 2] = t[2] * rng.uniform(0.9, 1.1, per_frame)
        K = scene.camera(im).K
        crops.append(
            extract_crops(scene.rgb(im), crop_affines(ts, K, bundle.spec), bundle.spec.size)
        )
    out = np.concatenate(crops)
    return out[rng.permutation(len(out))[:n]]


def _quantize(src: Path, calibration: np.ndarray) -> bytes:
    """The int8 QDQ model (bytes) of the encoder at ``src``, calibrated on crops (N,S,S,3);
    its uint8 input feeds the first convolution directly where that is bit-identical
    (export.qdq_input)."""
    model = quantize_qdq(src, calibration)
    return fold_input_chain(model, calibration) or model


def quantize_qdq(src: Path, calibration: np.ndarray) -> bytes:
    """onnxruntime's static QDQ quantisation (bytes) of the encoder at ``src`` (7-bit int8 weights
    per channel, uint8 activations), calibrated on crops (N,S,S,3) uint8 in batches of 32;
    its input still goes through the exporter's Cast / Mul chain."""
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.batches = iter(np.array_split(calibration, max(1, len(calibration) // 32)))

        def get_next(self) -> dict[str, np.ndarray] | None:
            batch = next(self.batches, None)
            return None if batch is None else {"crops": np.ascontiguousarray(batch)}

    root_logger = logging.getLogger()  # onnxruntime logs its advice on the root logger
    level = root_logger.level
    root_logger.setLevel(logging.ERROR)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            dst = Path(tmp) / "int8.onnx"
            quantize_static(
                str(src),
                str(dst),
                Reader(),
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                reduce_range=True,  # 7-bit weights: no u8s8 overflow on CPUs without VNNI
                weight_type=QuantType.QInt8,
                activation_type=QuantType.QUInt8,
            )
            return dst.read_bytes()
    finally:
        root_logger.setLevel(level)


def _embed(model: bytes | Path, crops: np.ndarray, threads: int) -> np.ndarray:
    """Unit-norm embeddings (N,E) of crops by the ONNX encoder ``model`` (bytes or a file)."""
    import onnxruntime as ort

    from chpf.bundle import session_options

    src = model if isinstance(model, bytes) else str(model)
    sess = ort.InferenceSession(
        src, sess_options=session_options(threads), providers=["CPUExecutionProvider"]
    )
    emb = np.concatenate([sess.run(None, {"crops": b})[0] for b in np.array_split(crops, 8)])
    return emb / np.linalg.norm(emb, axis=1, keepdims=True)


def quantize_bundle(
    bundle_dir: str | Path,
    crops: np.ndarray,
    min_cosine: float = 0.99,
    threads: int = 2,
    source: str = "",
) -> QuantizeReport:
    """Write the int8 encoders of the bundle in ``bundle_dir`` (module docstring), calibrated on
    the first half of ``crops`` (N,S,S,3) uint8 and checked on the second half; BundleError
    (nothing written) when an encoder's lowest cosine to float32 is below ``min_cosine``.
    ``source``: where the crops came from (recorded in the manifest)."""
    root = Path(bundle_dir)
    bundle = Bundle.load(root, threads=threads)
    half = len(crops) // 2
    if half < 8:
        raise BundleError(f"{root}: {len(crops)} calibration crops are too few (at least 16)")
    calib, held = crops[:half], crops[half:]
    files = {k: v for k, v in bundle.manifest["files"].items() if k in PRECISION_FILES and v}
    models: dict[str, bytes] = {}
    agree: dict[str, float] = {}
    for key, name in files.items():
        src = root / name
        models[key] = _quantize(src, calib)
        cos = np.sum(_embed(models[key], held, threads) * _embed(src, held, threads), axis=1)
        agree[key] = round(float(cos.min()), 5)
        if agree[key] < min_cosine:
            raise BundleError(
                f"{src}: int8 embeddings agree with float32 down to cosine {agree[key]:.4f} "
                f"only (at least {min_cosine} wanted); nothing written"
            )
    written = {
        key: Path(name).name.removesuffix(".onnx") + INT8_SUFFIX for key, name in files.items()
    }
    for key, name in written.items():
        atomic_write_bytes(root / name, models[key])
    manifest = json.loads((root / MANIFEST).read_text(encoding="utf-8"))
    for name in written.values():
        manifest["sha256"][name] = sha256_file(root / name)
    manifest.setdefault("precisions", {})["int8"] = {
        "files": written,
        "format": "onnxruntime QDQ, int8 weights per channel (7-bit range), uint8 activations",
        "calibration": {"crops": len(calib), "held_out": len(held), "source": source},
        "min_cosine_to_float32": agree,
    }
    write_manifest(root, manifest)
    return QuantizeReport(written, agree, (len(calib), len(held)))
