"""BOP results CSV: ``scene_id,im_id,obj_id,score,R,t,time``.

``R`` is 9 numbers separated by spaces (row-major), ``t`` 3 numbers in millimetres, ``time`` in
seconds (-1 = unknown). In memory ``t`` is in metres. The header line is optional on reading (as in
the BOP toolkit) and always written; a first line that is not numbers must be that header (a
renamed column is named). Blank lines are skipped. ``ResultsFormatError`` names the file
and the line for a wrong column count, a non-number, a non-finite value, or an ``R`` that is not a
rotation (``|R R^T - I| > 1e-3`` or ``det R < 0``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.errors import ResultsFormatError
from chpf.resumable_csv import ResumableCsv

__all__ = ["HEADER", "ResultRow", "ResultsAppender", "read_results_csv", "write_results_csv"]

HEADER = "scene_id,im_id,obj_id,score,R,t,time"
ORTHO_TOL = 1e-3
MM = 1000.0


@dataclass(eq=False)
class ResultRow:
    """One estimate: object-to-camera ``R`` (3,3), ``t`` (3,) metres, ``time`` s (-1 = unknown)."""

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    R: np.ndarray
    t: np.ndarray
    time: float = -1.0

    def __post_init__(self) -> None:
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)

    @property
    def key(self) -> tuple[int, int, int]:
        """(scene_id, im_id, obj_id)."""
        return (int(self.scene_id), int(self.im_id), int(self.obj_id))


def _fmt(x: float) -> str:
    """Shortest round-tripping text of a float (integers without '.0')."""
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def format_row(row: ResultRow) -> str:
    """One CSV line (no newline)."""
    R = " ".join(_fmt(v) for v in np.asarray(row.R, dtype=np.float64).ravel())
    t = " ".join(_fmt(v * MM) for v in np.asarray(row.t, dtype=np.float64).ravel())
    return (
        f"{int(row.scene_id)},{int(row.im_id)},{int(row.obj_id)},{_fmt(row.score)},"
        f"{R},{t},{_fmt(row.time)}"
    )


def parse_row(line: str, path: str | Path, lineno: int) -> ResultRow:
    """Parse one CSV line; ResultsFormatError naming ``path:lineno`` on any problem."""
    where = f"{path}:{lineno}"
    cols = line.strip().split(",")
    if len(cols) != 7:
        raise ResultsFormatError(f"{where}: expected 7 columns ({HEADER}), got {len(cols)}")
    names = ("scene_id", "im_id", "obj_id")
    ids = []
    for name, col in zip(names, cols[:3], strict=True):
        try:
            ids.append(int(col.strip()))
        except ValueError:
            raise ResultsFormatError(f"{where}: {name} {col.strip()!r} is not an integer") from None

    def floats(col: str, name: str, n: int) -> np.ndarray:
        parts = col.split()
        if len(parts) != n:
            raise ResultsFormatError(f"{where}: {name} must have {n} numbers, got {len(parts)}")
        try:
            arr = np.array([float(p) for p in parts], dtype=np.float64)
        except ValueError:
            raise ResultsFormatError(f"{where}: {name} {col.strip()!r} is not numeric") from None
        if not np.all(np.isfinite(arr)):
            raise ResultsFormatError(f"{where}: {name} has non-finite values")
        return arr

    score = floats(cols[3], "score", 1)[0]
    R = floats(cols[4], "R", 9).reshape(3, 3)
    t = floats(cols[5], "t", 3) / MM
    time = floats(cols[6], "time", 1)[0]
    dev = float(np.abs(R @ R.T - np.eye(3)).max())
    if dev > ORTHO_TOL or np.linalg.det(R) < 0:
        raise ResultsFormatError(
            f"{where}: R is not a rotation (|R R^T - I| = {dev:.2g}, det = {np.linalg.det(R):.3g})"
        )
    return ResultRow(ids[0], ids[1], ids[2], float(score), R, t, float(time))


def _is_header(line: str, path: str | Path) -> bool:
    """Whether the first line is a header (its first column is not a number); ResultsFormatError
    naming the first wrong column when it is one but not ``HEADER``."""
    cols = [c.strip() for c in line.split(",")]
    try:
        float(cols[0])
        return False
    except ValueError:
        pass
    want = HEADER.split(",")
    for i, name in enumerate(want):
        got = cols[i] if i < len(cols) else None
        if got != name:
            found = "nothing" if got is None else repr(got)
            raise ResultsFormatError(
                f"{path}:1: header is wrong: expected column {name!r} (column {i + 1}), found "
                f"{found} (the header is {HEADER})"
            )
    if len(cols) > len(want):
        raise ResultsFormatError(
            f"{path}:1: header is wrong: extra columns {cols[len(want) :]} (the header is {HEADER})"
        )
    return True


def _iter_lines(path: Path, text: str):
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or (lineno == 1 and _is_header(s, path)):
            continue
        yield lineno, s


def read_results_csv(path: str | Path) -> list[ResultRow]:
    """Read a BOP results CSV (t mm -> m)."""
    path = Path(path)
    if not path.is_file():
        raise ResultsFormatError(f"{path}: results file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ResultsFormatError(f"{path}: cannot read ({err})") from None
    return [parse_row(line, path, lineno) for lineno, line in _iter_lines(path, text)]


def write_results_csv(path: str | Path, rows: list[ResultRow]) -> None:
    """Write a BOP results CSV with header, atomically (t m -> mm)."""
    lines = [HEADER, *(format_row(r) for r in rows)]
    atomic_write_text(path, "\n".join(lines) + "\n")


class ResultsAppender(ResumableCsv):
    """Append rows to a results CSV one at a time, flushing each (resumable long runs; see
    ``chpf.resumable_csv``). Rows already in the file are validated; ``done_keys()`` lists their
    (scene_id, im_id, obj_id)."""

    def __init__(self, path: str | Path) -> None:
        super().__init__(path, HEADER, _row_keys)

    def append(self, row: ResultRow) -> None:
        """Write one row and flush it to the OS."""
        self.append_line(row.key, format_row(row))


def _row_keys(path: Path, text: str) -> list[tuple[int, int, int]]:
    return [parse_row(line, path, lineno).key for lineno, line in _iter_lines(path, text)]
