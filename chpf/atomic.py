"""Atomic file writes: a temp file in the target's folder, then ``os.replace``, so that a
reader (or a rerun after a crash) sees the old file or the new one, never half of one."""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np


@contextlib.contextmanager
def naming(path: str | os.PathLike) -> Iterator[None]:
    """Re-raise an OSError that names no file (a write's ENOSPC) as the same error naming
    ``path``, so that the one-line message says which output failed."""
    try:
        yield
    except OSError as err:
        if err.filename is not None or err.errno is None:
            raise
        raise OSError(err.errno, err.strerror, str(path)) from None


def _umask() -> int:
    """The process's umask (read by setting it and back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temp file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a written file gets the umask's
        with naming(path), os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Atomic UTF-8 text write (see ``atomic_write_bytes``)."""
    atomic_write_bytes(path, text.encode("utf-8"))


ZIP_METHODS = (zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
"""The compressions a compressed ``.npz`` member may take; np.load reads each of them."""


def _member(zf: zipfile.ZipFile, name: str, method: int) -> IO[bytes]:
    """A writable stream of the member ``name`` of ``zf`` (fixed timestamp, mode 644)."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = method
    info.external_attr = 0o644 << 16
    return zf.open(info, "w", force_zip64=True)


def _smallest_method(data: bytes) -> int:
    """The one of ``ZIP_METHODS`` that compresses ``data`` the most."""

    def size(method: int) -> int:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", allowZip64=True) as zf, _member(zf, "m", method) as f:
            f.write(data)
        return len(buf.getvalue())

    return min(ZIP_METHODS, key=size)


def npz_bytes(arrays: dict[str, np.ndarray], compressed: bool = False) -> bytes:
    """``.npz`` bytes that depend only on the arrays (fixed timestamps, key order); members are
    stored (memory-mappable) unless ``compressed``, where each takes the smallest of
    ``ZIP_METHODS`` (the mug bundle's depth crops: 6.5 MB in deflate, 3.8 in lzma, 3.5 in bzip2)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", allowZip64=True) as zf:
        for key, val in arrays.items():
            val = np.ascontiguousarray(val)
            if not compressed:
                with _member(zf, key + ".npy", zipfile.ZIP_STORED) as f:
                    np.lib.format.write_array(f, val, allow_pickle=False)
                continue
            npy = io.BytesIO()
            np.lib.format.write_array(npy, val, allow_pickle=False)
            data = npy.getvalue()
            with _member(zf, key + ".npy", _smallest_method(data)) as f:
                f.write(data)
    return buf.getvalue()


def atomic_save_npz(
    path: str | os.PathLike, arrays: dict[str, np.ndarray], compressed: bool = False
) -> None:
    """Atomically save ``arrays`` as an ``.npz`` file (see ``npz_bytes``)."""
    atomic_write_bytes(path, npz_bytes(arrays, compressed))
