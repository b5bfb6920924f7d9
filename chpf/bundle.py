"""Model bundles at run time: load, validate and call the exported networks (numpy + onnxruntime).

A bundle is a folder written by ``chpf-export``::

    BUNDLE_DIR/manifest.json      format_version, object, crop spec, file names and sha256 hashes
    BUNDLE_DIR/ae_encoder.onnx    "crops" uint8 (N,S,S,3) RGB -> "embedding" f32 (N,E), unit norm
    BUNDLE_DIR/ch_encoder.onnx    the classifier's observed-crop encoder (absent if AE one shared)
    BUNDLE_DIR/ch_head.onnx       "obs" (N,E), "cand" (N,E) float32 -> "p_misaligned" float32 (N,)
    BUNDLE_DIR/codebook.npz       rotations (K,3,3) f32 allocentric, ae_embeddings (K,E) f32,
                                  depth (K,Sd,Sd) f16 metres (0 = empty), and ch_embeddings
                                  (K,E) f32 unless the classifier shares the AE encoder

The depth crops are rendered at (S,S) with ``spec.K`` and reduced by an integer factor
``f = S // Sd`` (default 2): each depth pixel is the mean of the valid (non-zero) pixels of its
f x f block, or 0 when fewer than half of them are valid. The matching intrinsics are
``Bundle.depth_K``: focal ``f_r / f``, principal point ``(Sd - 1) / 2``.

This module never imports torch.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from chpf.bop import BopDataset
from chpf.crops import CropSpec
from chpf.errors import BundleError, ConfigError, ImageSizeError
from chpf.geometry import RotationGrid
from chpf.hashing import sha256_file
from chpf.providers import execution_providers

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
DIAMETER_TOL = 0.05
"""Relative difference of diameters above which a dataset's object is not the bundle's."""
SUPPORTED_CROP_SIZES: tuple[int, ...] = tuple(range(32, 257, 16))
"""Crop sizes S the runtime supports: multiples of 16 from 32 to 256."""

_REQUIRED_FILES = ("ae_encoder", "ch_head", "codebook")
PRECISIONS = ("float32", "int8")
"""Encoder precisions a bundle may hold: float32 (always) and int8 (``chpf-quantize``)."""
PRECISION_FILES = ("ae_encoder", "ch_obs_encoder")
"""The manifest ``files`` keys that a precision replaces (the encoders)."""
_CODEBOOK_ARRAYS = ("rotations", "ae_embeddings", "depth")  # + ch_embeddings unless shared


@dataclass(frozen=True)
class ObjectInfo:
    """The tracked object as recorded in the bundle (metres). ``file_offset`` (3,): where the
    origin of the frame the bundle tracks in (its mesh's bounding-box centre, as its crops are
    made: ``chpf.objects.ObjectModel.centred``) lies in the mesh file's frame; the tracker
    reports poses in the file's frame (``to_file_frame``). ``fingerprint``: the mesh file's."""

    name: str
    obj_id: int
    diameter: float
    symmetries_discrete: np.ndarray = field(repr=False)  # (n,4,4) float64, metres
    symmetries_continuous: list[dict[str, np.ndarray]] = field(repr=False)  # axis (3,), offset (3,)
    fingerprint: str = ""
    file_offset: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)

    def to_file_frame(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The translation (3,) metres, in the mesh file's frame, of the pose R (3,3), t (3,)
        of the bundle's frame: the same placement of the object, t - R file_offset."""
        return np.asarray(t, dtype=np.float64) - np.asarray(R, dtype=np.float64) @ self.file_offset

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObjectInfo:
        """Build from the manifest's ``object`` entry; KeyError/ValueError on malformed input."""
        disc = np.asarray(d.get("symmetries_discrete") or [], dtype=np.float64).reshape(-1, 4, 4)
        cont = [
            {
                "axis": np.asarray(s["axis"], dtype=np.float64).reshape(3),
                "offset": np.asarray(s.get("offset", (0.0, 0.0, 0.0)), dtype=np.float64).reshape(3),
            }
            for s in d.get("symmetries_continuous") or []
        ]
        return cls(
            name=str(d["name"]),
            obj_id=int(d["obj_id"]),
            diameter=float(d["diameter"]),
            symmetries_discrete=disc,
            symmetries_continuous=cont,
            fingerprint=str(d.get("fingerprint", "")),
            file_offset=np.asarray(d.get("file_offset", (0.0, 0.0, 0.0)), np.float64).reshape(3),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the manifest's ``object`` entry)."""
        return {
            "name": self.name,
            "obj_id": self.obj_id,
            "diameter": self.diameter,
            "symmetries_discrete": np.asarray(self.symmetries_discrete).tolist(),
            "symmetries_continuous": [
                {"axis": np.asarray(s["axis"]).tolist(), "offset": np.asarray(s["offset"]).tolist()}
                for s in self.symmetries_continuous
            ],
            "fingerprint": self.fingerprint,
            "file_offset": np.asarray(self.file_offset).tolist(),
        }


def check_crop_size(size: int, where: str) -> None:
    """Raise BundleError if the runtime does not support crops of ``size`` pixels."""
    if size not in SUPPORTED_CROP_SIZES:
        raise BundleError(
            f"{where}: crop size {size} is not supported "
            f"(supported: multiples of 16 from {SUPPORTED_CROP_SIZES[0]} "
            f"to {SUPPORTED_CROP_SIZES[-1]})"
        )


def session_options(threads: int, level: str = "all", spin: bool = True) -> ort.SessionOptions:
    """onnxruntime options: ``threads`` intra-op threads, graph optimisation ``level``.

    ``level`` is one of "disable", "basic", "extended", "all". ``spin=False`` stops idle worker
    threads from busy-waiting between calls (frees the cores for the rest of the filter at a
    small latency cost).
    """
    levels = {
        "disable": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
    }
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(threads)
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = levels[level]
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
    return opts


def _open_session(
    path: Path, opts: ort.SessionOptions, providers: list[str]
) -> ort.InferenceSession:
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=providers)
    except Exception as err:  # onnxruntime raises several private exception types
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise BundleError(f"{path}: onnxruntime cannot load the model ({msg})") from None


def _check_io(
    sess: ort.InferenceSession, path: Path, inputs: dict[str, str], outputs: dict[str, str]
) -> None:
    """Check input/output names and element types (``{"name": "tensor(float)"}``)."""
    got_in = {i.name: i.type for i in sess.get_inputs()}
    got_out = {o.name: o.type for o in sess.get_outputs()}
    if got_in != inputs or got_out != outputs:
        raise BundleError(
            f"{path}: unexpected ONNX inputs/outputs {got_in} -> {got_out} "
            f"(expected {inputs} -> {outputs})"
        )


def _encoder_io_check(sess: ort.InferenceSession, path: Path, size: int, dim: int) -> None:
    _check_io(sess, path, {"crops": "tensor(uint8)"}, {"embedding": "tensor(float)"})
    shape = sess.get_inputs()[0].shape
    if len(shape) != 4 or list(shape[1:]) != [size, size, 3]:
        raise BundleError(f"{path}: encoder input shape {shape} does not match crop size {size}")
    out = sess.get_outputs()[0].shape
    if len(out) != 2 or (isinstance(out[1], int) and out[1] != dim):
        raise BundleError(f"{path}: encoder output shape {out} does not match embedding_dim {dim}")


def _precision_files(manifest: dict[str, Any], precision: str, mpath: Path) -> dict[str, str]:
    """The encoder files (key -> name) of ``precision`` that replace the float32 ones."""
    if precision not in PRECISIONS:
        raise ConfigError(f"unknown precision {precision!r} (choose from {', '.join(PRECISIONS)})")
    if precision == "float32":
        return {}
    entry = manifest.get("precisions", {}).get(precision)
    if not isinstance(entry, dict) or not isinstance(entry.get("files"), dict):
        raise BundleError(
            f"{mpath}: no {precision} encoders in this bundle; make them with "
            f"chpf-quantize --bundle {mpath.parent}"
        )
    return {k: str(v) for k, v in entry["files"].items() if k in PRECISION_FILES}


class Bundle:
    """A loaded model bundle; all calls are batched over the first axis.

    Use ``Bundle.load(path, threads=2)``. Attributes: ``path``, ``manifest`` (dict), ``spec``
    (CropSpec), ``obj_info`` (ObjectInfo), ``grid`` (RotationGrid over the codebook),
    ``ae_codebook`` / ``ch_codebook`` (K,E) float32, ``embedding_dim``, ``codebook_size``,
    ``shares_encoder`` (the classifier's observed branch is the AE encoder), ``precision`` (of the
    encoders, PRECISIONS).
    """

    def __init__(
        self,
        path: Path,
        manifest: dict[str, Any],
        spec: CropSpec,
        obj_info: ObjectInfo,
        codebook: dict[str, np.ndarray],
        ae_session: ort.InferenceSession,
        ch_session: ort.InferenceSession | None,
        head_session: ort.InferenceSession,
    ) -> None:
        self.path = path
        self.manifest = manifest
        self.spec = spec
        self.obj_info = obj_info
        self.grid = RotationGrid(codebook["rotations"].astype(np.float64))
        self.ae_codebook: np.ndarray = codebook["ae_embeddings"]
        self.ch_codebook: np.ndarray = codebook["ch_embeddings"]
        self._depth: np.ndarray = codebook["depth"]
        self.embedding_dim = int(self.ae_codebook.shape[1])
        self.codebook_size = int(self.ae_codebook.shape[0])
        self.shares_encoder = ch_session is None
        self._ae = ae_session
        self._ch = ch_session
        self._head = head_session
        self.precision = "float32"  # of the encoders (PRECISIONS); set by ``load``
        self.device = "cpu"  # as asked (chpf.providers.DEVICES); set by ``load``
        self.providers: list[str] = ["CPUExecutionProvider"]  # those the sessions use

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        path: str | Path,
        threads: int = 2,
        verify: bool = True,
        spin: bool = True,
        precision: str = "float32",
        device: str = "auto",
    ) -> Bundle:
        """Load and validate the bundle in folder ``path``.

        ``threads``: onnxruntime intra-op threads per session (graph optimisation: all).
        ``verify``: check sha256 hashes. ``spin``: see ``session_options``. ``precision``: the
        encoders' (PRECISIONS; int8 needs the manifest's ``precisions.int8``, see
        ``export.quantize``).
        ``device``: where the networks run (chpf.providers.DEVICES; ConfigError for cuda
        without onnxruntime-gpu).
        Raises BundleError (one line naming the file) on a missing file, a hash mismatch, an
        unsupported format version or crop size, inconsistent shapes or a missing precision.
        """
        root = Path(path)
        mpath = root / MANIFEST
        if not root.is_dir():
            raise BundleError(f"{root}: bundle folder does not exist")
        if not mpath.is_file():
            raise BundleError(f"{mpath}: missing bundle manifest")
        try:
            manifest = json.loads(mpath.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise BundleError(f"{mpath}: unreadable manifest ({err})") from None
        if not isinstance(manifest, dict):
            raise BundleError(f"{mpath}: manifest is not a JSON object")
        version = manifest.get("format_version")
        if version != FORMAT_VERSION:
            raise BundleError(
                f"{mpath}: unsupported bundle format_version {version!r} "
                f"(this chpf reads version {FORMAT_VERSION})"
            )
        try:
            files: dict[str, str | None] = dict(manifest["files"])
            hashes: dict[str, str] = dict(manifest["sha256"])
            spec = CropSpec.from_dict(manifest["crop"])
            obj_info = ObjectInfo.from_dict(manifest["object"])
            dim = int(manifest["embedding_dim"])
            k = int(manifest["codebook_size"])
            shared = bool(manifest["ch_shares_ae_encoder"])
        except ConfigError as err:
            raise BundleError(f"{mpath}: malformed manifest ({err})") from None
        except (KeyError, TypeError, ValueError) as err:
            raise BundleError(f"{mpath}: malformed manifest (bad or missing {err})") from None
        files.update(_precision_files(manifest, precision, mpath))
        check_crop_size(int(spec.size), str(mpath))
        for key in _REQUIRED_FILES:
            if not files.get(key):
                raise BundleError(f"{mpath}: manifest names no '{key}' file")
        if shared != (files.get("ch_obs_encoder") is None):
            raise BundleError(
                f"{mpath}: ch_shares_ae_encoder={shared} but files.ch_obs_encoder="
                f"{files.get('ch_obs_encoder')!r}"
            )
        paths: dict[str, Path] = {}
        for key, name in files.items():
            if name is None:
                continue
            fpath = root / name
            if Path(name).name != name:
                raise BundleError(f"{mpath}: file name {name!r} must not contain a folder")
            if not fpath.is_file():
                raise BundleError(f"{fpath}: missing bundle file ({key})")
            if verify:
                want = hashes.get(name)
                if want is None:
                    raise BundleError(f"{mpath}: no sha256 recorded for {name}")
                if sha256_file(fpath) != want:
                    raise BundleError(f"{fpath}: sha256 mismatch (file modified or corrupt)")
            paths[key] = fpath

        codebook = _load_codebook(paths["codebook"], k, dim, int(spec.size))
        if int(threads) < 1:
            raise ConfigError(f"Bundle.load: threads must be >= 1, got {threads}")
        opts = session_options(int(threads), spin=spin)
        providers = execution_providers(device)
        ae = _open_session(paths["ae_encoder"], opts, providers)
        _encoder_io_check(ae, paths["ae_encoder"], int(spec.size), dim)
        ch = None
        if not shared:
            ch = _open_session(paths["ch_obs_encoder"], opts, providers)
            _encoder_io_check(ch, paths["ch_obs_encoder"], int(spec.size), dim)
        head = _open_session(paths["ch_head"], opts, providers)
        _check_io(
            head,
            paths["ch_head"],
            {"obs": "tensor(float)", "cand": "tensor(float)"},
            {"p_misaligned": "tensor(float)"},
        )
        bundle = cls(root, manifest, spec, obj_info, codebook, ae, ch, head)
        bundle.precision, bundle.device = precision, device
        bundle.providers = list(ae.get_providers())
        return bundle

    # ------------------------------------------------------------------ data
    def check_dataset(
        self, dataset: BopDataset, obj_id: int | None = None, tol: float = DIAMETER_TOL
    ) -> None:
        """Refuse (BundleError naming both) a dataset whose object ``obj_id`` (None = this
        bundle's obj_id) is another object: its ``models_info.json`` diameter differs from the
        manifest's by more than ``tol`` (relative), or the mesh fingerprint that
        ``chpf-gen-data`` recorded in its ``sequences_info.json`` differs from the manifest's.
        Nothing recorded: nothing to check.
        """
        obj = self.obj_info
        oid = obj.obj_id if obj_id is None else int(obj_id)
        mine = f"the bundle's object {obj.name!r} ({self.path / MANIFEST})"
        info = dataset.models_info().get(oid) if dataset.models_info_path.is_file() else None
        if info is not None and abs(info.diameter - obj.diameter) > tol * obj.diameter:
            raise BundleError(
                f"{dataset.models_info_path}: obj_id {oid} has diameter "
                f"{info.diameter * 1000:.1f} mm but {mine} has {obj.diameter * 1000:.1f} mm "
                f"(more than {tol:.0%} apart): another object; track it with its own bundle"
            )
        recorded = dataset.recorded_fingerprints().get(oid)
        if recorded and obj.fingerprint and recorded != obj.fingerprint:
            raise BundleError(
                f"{dataset.sequences_info_path}: obj_id {oid} has mesh fingerprint "
                f"{recorded[:10]} but {mine} has {obj.fingerprint[:10]}: another mesh; track it "
                "with its own bundle"
            )

    # ------------------------------------------------------------------ calls
    def _check_crops(self, crops: np.ndarray) -> np.ndarray:
        s = self.spec.size
        if crops.ndim != 4 or crops.shape[1:] != (s, s, 3):
            raise ImageSizeError(
                f"{self.path}: crops of shape {crops.shape}, the bundle expects (N,{s},{s},3)"
            )
        if crops.dtype != np.uint8:
            raise ImageSizeError(f"{self.path}: crops must be uint8 RGB, got {crops.dtype}")
        return np.ascontiguousarray(crops)  # no copy when already C-contiguous

    def _encode(self, sess: ort.InferenceSession, crops: np.ndarray) -> np.ndarray:
        crops = self._check_crops(crops)
        if crops.shape[0] == 0:
            return np.zeros((0, self.embedding_dim), np.float32)
        return sess.run(None, {"crops": crops})[0]

    def embed(self, crops: np.ndarray) -> np.ndarray:
        """Autoencoder embeddings of uint8 RGB crops (N,S,S,3) -> (N,E) float32, unit norm."""
        return self._encode(self._ae, crops)

    def ch_embed(self, crops: np.ndarray) -> np.ndarray:
        """Classifier observed-branch embeddings (N,S,S,3) -> (N,E); same as ``embed`` if shared."""
        return self._encode(self._ae if self._ch is None else self._ch, crops)

    def p_misaligned(self, obs_emb: np.ndarray, codebook_idx: np.ndarray) -> np.ndarray:
        """Classifier probability that each hypothesis is misaligned: (N,E), (N,) int -> (N,).

        ``obs_emb`` comes from ``ch_embed``; ``codebook_idx`` picks the candidate embeddings.
        """
        obs = np.ascontiguousarray(obs_emb, dtype=np.float32)
        idx = np.asarray(codebook_idx)
        if obs.ndim != 2 or obs.shape[1] != self.embedding_dim or idx.shape != obs.shape[:1]:
            raise ValueError(
                f"p_misaligned: obs_emb {obs.shape} and codebook_idx {idx.shape} must be "
                f"(N,{self.embedding_dim}) and (N,)"
            )
        if obs.shape[0] == 0:
            return np.zeros(0, np.float32)
        cand = self.ch_codebook[idx]
        return self._head.run(None, {"obs": obs, "cand": cand})[0].reshape(-1)

    def cosine(self, emb: np.ndarray, codebook_idx: np.ndarray) -> np.ndarray:
        """Cosine similarity of AE embeddings (N,E) with codebook entries (N,) -> (N,) float32."""
        return np.einsum("ne,ne->n", emb, self.ae_codebook[np.asarray(codebook_idx)])

    def nearest(self, R_allo: np.ndarray) -> np.ndarray:
        """Nearest codebook entries of allocentric rotations (N,3,3) -> (N,) int64."""
        return self.grid.nearest(np.asarray(R_allo))

    def codebook_depth(self, idx: np.ndarray) -> np.ndarray:
        """Rendered depth crops of codebook entries (N,) -> (N,Sd,Sd) float32 metres (0 = empty).

        The object is at (0, 0, D_r); intrinsics ``depth_K``.
        """
        return self._depth[np.asarray(idx)].astype(np.float32)

    @property
    def depth_size(self) -> int:
        """Sd, the side of the codebook depth crops in pixels."""
        return int(self._depth.shape[1])

    @property
    def depth_K(self) -> np.ndarray:
        """(3,3) intrinsics of the codebook depth crops (crop K scaled by Sd / S)."""
        sd = self.depth_size
        f = self.spec.focal * sd / self.spec.size
        c = (sd - 1) / 2.0
        return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])

    def __repr__(self) -> str:
        return (
            f"Bundle({str(self.path)!r}, object={self.obj_info.name!r}, S={self.spec.size}, "
            f"E={self.embedding_dim}, K={self.codebook_size}, shared={self.shares_encoder})"
        )


def _load_codebook(path: Path, k: int, dim: int, size: int) -> dict[str, np.ndarray]:
    """Read and check codebook.npz against the manifest's K, E and S."""
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [a for a in _CODEBOOK_ARRAYS if a not in z.files]
            if missing:
                raise BundleError(f"{path}: codebook lacks arrays {missing}")
            arrays = {a: z[a] for a in _CODEBOOK_ARRAYS}
            if "ch_embeddings" in z.files:
                arrays["ch_embeddings"] = z["ch_embeddings"]
    except BundleError:
        raise
    except Exception as err:
        raise BundleError(f"{path}: unreadable codebook ({type(err).__name__}: {err})") from None
    rot, ae, depth = (arrays[a] for a in _CODEBOOK_ARRAYS)
    ch = arrays.get("ch_embeddings", ae)
    if rot.shape != (k, 3, 3):
        raise BundleError(f"{path}: rotations have shape {rot.shape}, expected ({k}, 3, 3)")
    for name, arr in (("ae_embeddings", ae), ("ch_embeddings", ch)):
        if arr.shape != (k, dim):
            raise BundleError(f"{path}: {name} have shape {arr.shape}, expected ({k}, {dim})")
    if depth.ndim != 3 or depth.shape[0] != k or depth.shape[1] != depth.shape[2]:
        raise BundleError(f"{path}: depth has shape {depth.shape}, expected ({k}, Sd, Sd)")
    if depth.shape[1] == 0 or size % depth.shape[1] != 0:
        raise BundleError(f"{path}: depth size {depth.shape[1]} does not divide crop size {size}")
    err = np.abs(np.einsum("kij,klj->kil", rot, rot) - np.eye(3)).max() if k else 0.0
    if err > 1e-3:
        raise BundleError(f"{path}: codebook rotations are not orthonormal (error {err:.2g})")
    arrays["ae_embeddings"] = np.ascontiguousarray(ae, dtype=np.float32)
    arrays["ch_embeddings"] = (
        arrays["ae_embeddings"] if ch is ae else np.ascontiguousarray(ch, dtype=np.float32)
    )
    return arrays
