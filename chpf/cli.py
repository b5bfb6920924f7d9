"""Shared helpers for the command-line tools: one-line errors, atomic file writes and
argument types."""

from __future__ import annotations

import argparse
import functools
import io
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from chpf.errors import ChpfError


def run_main(main: Callable[[list[str] | None], int]) -> Callable[[], None]:
    """Wrap ``main(argv) -> exit code`` for a console script: ChpfError -> one line, exit 2."""

    @functools.wraps(main)
    def cli() -> None:
        try:
            code = main(None)
        except ChpfError as err:
            print(f"error: {err}", file=sys.stderr)
            sys.exit(2)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            sys.exit(130)
        sys.exit(code or 0)

    return cli


def scene_list(text: str) -> list[int]:
    """argparse type of ``--scenes``: comma-separated scene ids ("48,49") -> [48, 49]."""
    try:
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated scene ids, got {text!r}"
        ) from None


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temp file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Atomic UTF-8 text write (see ``atomic_write_bytes``)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_save_npz(
    path: str | os.PathLike, compressed: bool = False, **arrays: np.ndarray
) -> None:
    """Atomically save arrays as an ``.npz`` file (uncompressed unless ``compressed``)."""
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
