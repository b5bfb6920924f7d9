"""Write a bundle folder atomically: build it in a temp folder next to OUT, then rename.

A crash leaves OUT as it was (the temp folder is removed). An existing OUT is replaced only if
it is empty or holds a bundle of the same object (any bundle with ``overwrite``); a non-empty
folder that is not a bundle is never touched.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from chpf.bundle import MANIFEST
from chpf.errors import BundleError
from chpf.hashing import sha256_bytes


def existing_bundle_object(out: Path) -> str | None:
    """Object name of the bundle in ``out`` ("" if unreadable), None if ``out`` is absent/empty.

    Raises BundleError if ``out`` is a file or a non-empty folder without a bundle manifest.
    """
    if not out.exists():
        return None
    if not out.is_dir():
        raise BundleError(f"{out}: exists and is not a folder")
    if not any(out.iterdir()):
        return None
    mpath = out / MANIFEST
    if not mpath.is_file():
        raise BundleError(
            f"{out}: folder is not empty and holds no bundle ({MANIFEST}); refusing to replace it"
        )
    try:
        return str(json.loads(mpath.read_text(encoding="utf-8"))["object"]["name"])
    except (OSError, ValueError, KeyError, TypeError):
        return ""


def check_out(out: Path, object_name: str, overwrite: bool) -> None:
    """Refuse (BundleError) an OUT that holds a bundle of another object, unless ``overwrite``."""
    name = existing_bundle_object(out)
    if name is None or name == object_name or overwrite:
        return
    what = f"object '{name}'" if name else "an unreadable manifest"
    raise BundleError(
        f"{out}: holds a bundle of {what}, not '{object_name}' (use --overwrite to replace it)"
    )


@contextlib.contextmanager
def staging_dir(out: Path) -> Iterator[Path]:
    """A fresh temp folder next to ``out``; removed on exit unless it was renamed away."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.tmp-"))
    umask = os.umask(0o022)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it 0700; a bundle folder is a normal folder
    try:
        yield tmp
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_files(folder: Path, files: dict[str, bytes]) -> dict[str, str]:
    """Write ``{name: bytes}`` into ``folder`` (fsync'd); returns ``{name: sha256 hex}``."""
    hashes: dict[str, str] = {}
    for name, data in files.items():
        with open(folder / name, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        hashes[name] = sha256_bytes(data)
    return hashes


def write_manifest(folder: Path, manifest: dict[str, Any]) -> None:
    """Write ``manifest.json`` (sorted keys, indented) into ``folder``."""
    text = json.dumps(manifest, indent=2, sort_keys=True, allow_nan=False) + "\n"
    write_files(folder, {MANIFEST: text.encode("utf-8")})


def install(tmp: Path, out: Path) -> None:
    """Move the finished ``tmp`` folder to ``out``, replacing an existing ``out``."""
    old: Path | None = None
    if out.exists():
        old = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.old-"))
        os.rmdir(old)
        os.rename(out, old)
    try:
        os.rename(tmp, out)
    except OSError:
        if old is not None:
            os.rename(old, out)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def to_jsonable(obj: Any) -> Any:
    """Recursively turn numpy arrays/scalars, tuples, sets and paths into JSON types."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else str(obj)
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)
