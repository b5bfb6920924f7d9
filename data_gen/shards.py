"""Sample shards on disk: ``DIR/manifest.json`` + ``DIR/shard_{i:05d}.npz`` (numpy only, no torch).

Shards are uncompressed ``.npz`` files written byte-deterministically (fixed zip timestamps) and
atomically. The manifest lists every planned shard; a shard file that exists is complete (it
was renamed into place only after it was fully written), which is what resume relies on.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.errors import DatasetError, MeshError
from chpf.outdir import differing_keys

FORMAT_VERSION = 1
MANIFEST = "manifest.json"

# name -> (dtype, per-sample shape given S)
FIELDS: dict[str, dict[str, tuple[np.dtype, Any]]] = {
    "pairs": {
        "obs_rgb": (np.dtype(np.uint8), lambda s: (s, s, 3)),
        "cand_rgb": (np.dtype(np.uint8), lambda s: (s, s, 3)),
        "cand_depth": (np.dtype(np.float16), lambda s: (s, s)),
        "aligned": (np.dtype(np.uint8), lambda s: ()),
        "obs_R_allo": (np.dtype(np.float32), lambda s: (3, 3)),
        "cand_R_allo": (np.dtype(np.float32), lambda s: (3, 3)),
        "angle_deg": (np.dtype(np.float32), lambda s: ()),
        "visib_fract": (np.dtype(np.float32), lambda s: ()),
        "depth_ratio": (np.dtype(np.float32), lambda s: ()),
    },
    "ae": {
        "input_rgb": (np.dtype(np.uint8), lambda s: (s, s, 3)),
        "target_rgb": (np.dtype(np.uint8), lambda s: (s, s, 3)),
        "target_mask": (np.dtype(np.bool_), lambda s: (s, s)),
        "R_allo": (np.dtype(np.float32), lambda s: (3, 3)),
        "visib_fract": (np.dtype(np.float32), lambda s: ()),
    },
}


def shard_name(i: int) -> str:
    """File name of shard ``i``."""
    return f"shard_{i:05d}.npz"


def shard_sizes(num_samples: int, per_shard: int) -> list[int]:
    """Sample counts of the shards: full shards, the last one holds the remainder."""
    full, rest = divmod(int(num_samples), int(per_shard))
    return [int(per_shard)] * full + ([rest] if rest else [])


def empty_shard(kind: str, n: int, size: int) -> dict[str, np.ndarray]:
    """Zero-filled arrays of one shard of ``kind`` with ``n`` samples of crop size ``size``."""
    return {k: np.zeros((n, *shp(size)), dtype=dt) for k, (dt, shp) in FIELDS[kind].items()}


def check_shard(kind: str, arrays: dict[str, np.ndarray], n: int, size: int) -> None:
    """Raise ``DatasetError`` unless ``arrays`` has exactly the fields, dtypes and shapes."""
    if set(arrays) != set(FIELDS[kind]):
        raise DatasetError(f"{kind} shard: fields {sorted(arrays)} != {sorted(FIELDS[kind])}")
    for k, (dt, shp) in FIELDS[kind].items():
        a = arrays[k]
        if a.dtype != dt or a.shape != (n, *shp(size)):
            raise DatasetError(
                f"{kind} shard: {k} is {a.dtype} {a.shape}, want {dt} {(n, *shp(size))}"
            )


# ----------------------------------------------------------------------------- npz I/O


def load_npz(path: str | Path, mmap: bool = False) -> dict[str, np.ndarray]:
    """Arrays of an ``.npz``; with ``mmap`` (uncompressed members only) read-only memory maps."""
    path = Path(path)
    try:
        if not mmap:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        out = {}
        with zipfile.ZipFile(path) as zf, open(path, "rb") as f:
            for info in zf.infolist():
                if info.compress_type != zipfile.ZIP_STORED or not info.filename.endswith(".npy"):
                    raise DatasetError(f"{path}: member {info.filename} cannot be memory-mapped")
                f.seek(info.header_offset)
                local = f.read(30)
                name_len = int.from_bytes(local[26:28], "little")
                extra_len = int.from_bytes(local[28:30], "little")
                f.seek(info.header_offset + 30 + name_len + extra_len)
                version = np.lib.format.read_magic(f)
                read_header = {
                    (1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0,
                }.get(version)
                if read_header is None:
                    raise DatasetError(f"{path}: unsupported .npy version {version}")
                shape, fortran, dtype = read_header(f)
                out[info.filename[:-4]] = np.memmap(
                    path,
                    dtype=dtype,
                    mode="r",
                    offset=f.tell(),
                    shape=shape,
                    order="F" if fortran else "C",
                )
        return out
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise DatasetError(f"{path}: unreadable shard ({err})") from None


# ----------------------------------------------------------------------------- manifest


def make_manifest(
    kind: str,
    object_name: str,
    object_fingerprint: str,
    crop: dict,
    seed: int,
    config: dict,
    samples_per_shard: int,
    num_samples: int,
    extra: dict | None = None,
) -> dict:
    """The manifest dict (spec fields first, then ``extra`` informative fields)."""
    sizes = shard_sizes(num_samples, samples_per_shard)
    man = {
        "kind": kind,
        "format_version": FORMAT_VERSION,
        "object": object_name,
        "object_fingerprint": object_fingerprint,
        "crop": crop,
        "seed": int(seed),
        "config": config,
        "samples_per_shard": int(samples_per_shard),
        "num_samples": int(num_samples),
        "shards": [{"file": shard_name(i), "n": n} for i, n in enumerate(sizes)],
    }
    man.update(extra or {})
    return man


# Keys whose difference means "made with another config" (informative extras are not compared).
IDENTITY_KEYS = (
    "kind",
    "format_version",
    "object_fingerprint",
    "crop",
    "seed",
    "config",
    "samples_per_shard",
    "num_samples",
)


def manifest_object(data_dir: str | Path, override: str | None = None, unit: str | None = None):
    """The ObjectModel a data folder was made from, ``centred`` as its crops are: ``override``
    (built-in name or mesh path, in ``unit``) if given, else the mesh file its manifest records
    (``object_source``, made by this version on) or the built-in it names. DatasetError (one
    line, naming the manifest and ``--object MESH``) when that file has moved or the object's
    fingerprint differs from the manifest's."""
    from chpf.objects import get_object, object_fingerprint

    path = Path(data_dir) / MANIFEST
    man = read_manifest(data_dir)
    source = man.get("object_source") or {}
    name = override or source.get("path") or man.get("object")
    if override is None and source.get("path") and not Path(source["path"]).is_file():
        raise DatasetError(
            f"{path}: made from the mesh {source['path']}, which is not there any more; pass "
            "--object MESH (and --unit) with the mesh chpf-gen-data used"
        )
    obj_unit = unit or (source.get("unit") if override is None else None) or "m"
    try:
        obj = get_object(str(name), unit=obj_unit, allow_size=True).centred()  # checked before
    except MeshError as err:
        raise DatasetError(
            f"{path}: {err}; pass --object MESH with the mesh chpf-gen-data used"
        ) from None
    fp = man.get("object_fingerprint")
    if fp and object_fingerprint(obj) != fp:
        raise DatasetError(
            f"{path}: made for another object than '{name}' (fingerprints differ); pass "
            "--object MESH with the mesh chpf-gen-data used"
        )
    return obj


def read_manifest(out_dir: str | Path) -> dict:
    """Parsed ``DIR/manifest.json`` (``DatasetError`` if missing or malformed)."""
    path = Path(out_dir) / MANIFEST
    try:
        man = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{path}: not found (not a chpf-gen-data output folder)") from None
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path}: unreadable manifest ({err})") from None
    if not isinstance(man, dict) or man.get("kind") not in FIELDS or "shards" not in man:
        raise DatasetError(f"{path}: not a pairs/ae manifest")
    return man


def prepare_output(
    out_dir: str | Path, manifest: dict, overwrite: bool, dry_run: bool = False
) -> None:
    """Create/validate ``out_dir`` for ``manifest``; write the manifest (atomic).

    ``dry_run``: only check (raise the refusal errors), change nothing.

    A folder with a manifest of another config is refused (``DatasetError``) unless
    ``overwrite``, which deletes its shard files first. A non-empty folder without a manifest is
    refused too unless ``overwrite`` (its other files are left alone).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out}: exists and is not a folder")
    man_path = out / MANIFEST
    if man_path.exists():
        try:
            old = json.loads(man_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = {}
        diff = ["manifest"]
        if isinstance(old, dict):
            diff = [
                d for k in IDENTITY_KEYS for d in differing_keys(old.get(k), manifest.get(k), k)
            ]
        if diff:
            if not overwrite:
                shown = ", ".join(diff[:4]) + (" ..." if len(diff) > 4 else "")
                raise DatasetError(
                    f"{out}: holds data made with another config (differs in {shown}); "
                    "use --overwrite to replace it"
                )
            if dry_run:
                return
            for p in out.glob("shard_*.npz"):
                p.unlink()
    elif out.exists() and any(out.iterdir()) and not overwrite:
        raise DatasetError(
            f"{out}: folder is not empty and has no {MANIFEST}; use another folder or --overwrite"
        )
    if dry_run:
        return
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(man_path, json.dumps(manifest, indent=1, sort_keys=False) + "\n")


def shard_complete(out_dir: str | Path, manifest: dict, i: int) -> bool:
    """True if shard ``i`` exists with the planned sample count."""
    entry = manifest["shards"][i]
    path = Path(out_dir) / entry["file"]
    if not path.is_file():
        return False
    try:
        arrays = load_npz(path, mmap=True)
    except DatasetError:
        return False
    fields = FIELDS[manifest["kind"]]
    return set(arrays) == set(fields) and all(len(a) == entry["n"] for a in arrays.values())


# ----------------------------------------------------------------------------- reader


class ShardDataset:
    """Numpy-only reader of a pairs/ae output folder.

    ``len()`` samples; ``num_shards``; ``load_shard(i)`` -> dict of arrays (read into memory;
    read-only memory maps when ``mmap``); ``ds[idx]`` -> dict of one sample (copies, read
    through memory maps, so random access is cheap). ``manifest``: the parsed manifest.
    Missing shards raise ``DatasetError`` unless ``allow_partial`` (then only the complete
    shards are indexed).
    """

    def __init__(self, path: str | Path, mmap: bool = False, allow_partial: bool = False) -> None:
        self.path = Path(path)
        self.manifest = read_manifest(self.path)
        self.kind: str = self.manifest["kind"]
        self.mmap = mmap
        entries = self.manifest["shards"]
        present = [(self.path / e["file"]).is_file() for e in entries]
        if not all(present) and not allow_partial:
            missing = [e["file"] for e, ok in zip(entries, present, strict=True) if not ok]
            raise DatasetError(
                f"{self.path}: {len(missing)} of {len(entries)} shards missing "
                f"(first {missing[0]}); rerun chpf-gen-data with the same arguments to finish"
            )
        self._shards = [i for i, ok in enumerate(present) if ok]
        counts = np.array([entries[i]["n"] for i in self._shards], dtype=np.int64)
        self._starts = np.concatenate([[0], np.cumsum(counts)])
        self._cache: tuple[int, dict[str, np.ndarray]] | None = None

    @property
    def num_shards(self) -> int:
        return len(self._shards)

    @property
    def crop_size(self) -> int:
        return int(self.manifest["crop"]["size"])

    def __len__(self) -> int:
        return int(self._starts[-1])

    def load_shard(self, i: int, mmap: bool | None = None) -> dict[str, np.ndarray]:
        """Arrays of the ``i``-th (present) shard, checked against the spec's fields."""
        entry = self.manifest["shards"][self._shards[i]]
        path = self.path / entry["file"]
        arrays = load_npz(path, mmap=self.mmap if mmap is None else mmap)
        try:
            check_shard(self.kind, arrays, entry["n"], self.crop_size)
        except DatasetError as err:
            raise DatasetError(f"{path}: {err}") from None
        return arrays

    def __getitem__(self, idx: int) -> dict[str, np.ndarray]:
        n = len(self)
        if idx < 0:
            idx += n
        if not 0 <= idx < n:
            raise IndexError(f"sample {idx} out of range (0..{n - 1})")
        s = int(np.searchsorted(self._starts, idx, side="right") - 1)
        if self._cache is None or self._cache[0] != s:
            self._cache = (s, self.load_shard(s, mmap=True))
        j = idx - int(self._starts[s])
        return {k: np.array(v[j]) for k, v in self._cache[1].items()}
