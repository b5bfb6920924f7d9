"""Append-only CSV files that a rerun resumes: the one writer under the BOP result CSVs
(``chpf.results.ResultsAppender``) and the tracking frame logs (``chpf.tracking.runlog.FrameLog``).

Opening an existing file cuts a partial last line (a run killed mid-write), reads the keys of
the rows already there (``done_keys``, to skip them) and appends after them; a new or empty
file gets the header. Every row is flushed to the OS as it is written, and ``close`` fsyncs.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO

from chpf.atomic import naming

Key = tuple[int, int, int]
"""(scene_id, im_id, obj_id) of a row."""


class ResumableCsv:
    """See the module docstring. ``read_keys(path, text)`` returns the keys of the rows in the
    file's complete lines (raising a ChpfError naming the file on malformed rows)."""

    def __init__(
        self, path: str | Path, header: str, read_keys: Callable[[Path, str], Iterable[Key]]
    ) -> None:
        self.path = Path(path)
        self._keys: set[Key] = set()
        text = ""
        if self.path.is_file():
            data = self.path.read_bytes()
            if data and not data.endswith(b"\n"):
                cut = data.rfind(b"\n") + 1
                with open(self.path, "r+b") as f:
                    f.truncate(cut)
                data = data[:cut]
            text = data.decode("utf-8", errors="replace")
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        if text.strip():
            self._keys.update(read_keys(self.path, text))
        self._f = open(self.path, "a", encoding="utf-8", newline="")
        if not text.strip():
            with naming(self.path):
                self._f.write(header + "\n")
                self._f.flush()

    def append_line(self, key: Key, line: str) -> None:
        """Write one row (``line`` without newline) and flush it to the OS."""
        with naming(self.path):
            self._f.write(line + "\n")
            self._f.flush()
        self._keys.add(key)

    def done_keys(self) -> set[Key]:
        """Keys of the rows in the file, including the ones appended so far."""
        return set(self._keys)

    def close(self) -> None:
        """Flush, fsync and close (idempotent). On a write error (a full disk) the file is
        closed all the same, its unwritten tail dropped, and the error raised once."""
        if self._f.closed:
            return
        try:
            with naming(self.path):
                self._f.flush()
                os.fsync(self._f.fileno())
        except OSError:
            _close_quietly(self._f)
            raise
        self._f.close()

    def __enter__(self) -> ResumableCsv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        f = getattr(self, "_f", None)
        if f is not None:
            _close_quietly(f)


def _close_quietly(f: IO[str]) -> None:
    """Close ``f``; a failing final flush (the error was raised where it happened) is dropped."""
    with contextlib.suppress(OSError):
        f.close()
