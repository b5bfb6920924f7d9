"""sha256 fingerprints of bytes and files (bundle manifests, recorded run settings)."""

from __future__ import annotations

import hashlib
import os

CHUNK = 1 << 22
"""Bytes read at a time when hashing a file (4 MiB)."""


def sha256_bytes(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes, read in chunks of CHUNK."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(CHUNK):
            h.update(block)
    return h.hexdigest()
