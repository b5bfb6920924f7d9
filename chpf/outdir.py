"""Output folders of the chpf commands: checked first, one writer at a time, and outputs of one
setting only.

``check_out_dir(folder)`` / ``check_out_file(path)`` refuse (OutputError, one line) an output
that cannot be written before a command does any work: an existing file where a folder is due, a
folder where a file is due, a path under a file, a place where nothing can be created. They
create nothing.

``lock_output_dir(folder, command)`` takes an exclusive ``flock`` on ``FOLDER/.chpf.lock`` for as
long as a command writes there (``lock_output_path`` beside a file or folder that is replaced
as a whole): a second writer (chpf-track, chpf-gen-data, chpf-export,
chpf-eval --json) on the same folder refuses in one line instead of interleaving its rows. The
lock dies with the process, so a killed run leaves nothing to clean up.

``claim_settings(folder, name, settings, overwrite)`` records the settings a command's outputs
were made with (``FOLDER/NAME``, JSON) and refuses a rerun with other settings unless
``overwrite``, so that a resumed folder never mixes two runs.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from chpf.atomic import atomic_write_text, naming
from chpf.errors import OutputError

LOCK_NAME = ".chpf.lock"


def check_out_dir(folder: str | os.PathLike) -> Path:
    """Refuse (OutputError) an output folder that cannot be created or written; returns it.

    Its nearest existing ancestor (itself if it exists) must be a folder in which a file can be
    created (probed with a temporary file, so a read-only or virtual place such as /proc fails).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder")
    base = folder
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"{folder}: cannot create the folder ({base} is a file, not a folder)")
    try:
        with tempfile.TemporaryFile(dir=base):
            pass
    except OSError as err:
        what = "write in the folder" if base == folder else "create the folder"
        raise OutputError(f"{folder}: cannot {what} ({base}: {err.strerror})") from None
    return folder


def check_out_file(path: str | os.PathLike) -> Path:
    """Refuse (OutputError) an output file that cannot be written: an existing folder, or a
    folder for it that cannot be created or written (``check_out_dir``); returns it."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not a file; give a file name")
    check_out_dir(path.parent)
    return path


def make_output_dir(folder: str | os.PathLike) -> Path:
    """Create ``folder`` (and parents) after ``check_out_dir``; OutputError naming it when that
    is impossible."""
    folder = check_out_dir(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError) as err:
        raise OutputError(f"{folder}: cannot create the output folder ({err})") from None
    return folder


@contextlib.contextmanager
def _hold_lock(path: Path, what: Path, command: str) -> Iterator[None]:
    """Hold an exclusive flock on ``path`` for ``what``; OutputError when another holds it."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise OutputError(f"{path}: cannot open the lock file ({err})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", errors="replace").strip()
            raise OutputError(
                f"{what}: another command is writing here ({holder or 'unknown'}); "
                "wait for it to finish or choose another output"
            ) from None
        with naming(path):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{command}, pid {os.getpid()}".encode(), 0)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


@contextlib.contextmanager
def lock_output_dir(folder: str | os.PathLike, command: str) -> Iterator[Path]:
    """Hold the write lock of a folder written in place (``FOLDER/.chpf.lock``; the folder is
    created if needed) while the block runs; yields the folder."""
    folder = make_output_dir(folder)
    with _hold_lock(folder / LOCK_NAME, folder, command):
        yield folder


@contextlib.contextmanager
def lock_output_path(path: str | os.PathLike, command: str) -> Iterator[Path]:
    """Hold the write lock of a file or folder that is replaced as a whole (a bundle folder, a
    JSON report): the lock file ``.NAME.chpf.lock`` sits beside it; yields the path."""
    path = Path(path)
    make_output_dir(path.parent)
    with _hold_lock(path.parent / f".{path.name}{LOCK_NAME}", path, command):
        yield path


def differing_keys(a: Any, b: Any, prefix: str = "") -> list[str]:
    """Dotted names of the leaves where two JSON-like values differ ("config.seed", ...)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            out += differing_keys(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else str(k))
        return out
    return [] if a == b else [prefix]


def claim_settings(
    folder: str | os.PathLike, name: str, settings: dict[str, Any], overwrite: bool
) -> bool:
    """Record ``settings`` as ``FOLDER/NAME`` unless the same are recorded already.

    Returns True when the folder's earlier outputs are stale (made with other or unrecorded
    settings, replaced as ``overwrite`` allows): the caller then removes them. Raises
    OutputError when they are stale and ``overwrite`` is False.
    """
    folder = Path(folder)
    path = folder / name
    settings = json.loads(json.dumps(settings))  # as it reads back (tuples -> lists)
    if path.is_file():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            old = f"unreadable ({err})"
        if not isinstance(old, dict):
            if not overwrite:
                raise OutputError(f"{path}: not a settings record ({old}); use --overwrite")
            old = {}
        if old == settings:
            return False
        if not overwrite:
            changed = differing_keys(old, settings)
            shown = ", ".join(changed[:4]) + (" ..." if len(changed) > 4 else "")
            raise OutputError(
                f"{folder}: holds outputs made with other settings ({shown} differ, see {name}); "
                "use --overwrite to replace them or choose another folder"
            )
        stale = True
    else:
        stale = any(p.name != LOCK_NAME for p in folder.iterdir())
        if stale and not overwrite:
            raise OutputError(
                f"{folder}: folder is not empty and has no {name}; use --overwrite or another "
                "folder"
            )
    atomic_write_text(path, json.dumps(settings, indent=1, sort_keys=True) + "\n")
    return stale
