"""What every console script shares: one-line errors with exit 2, and argument types."""

from __future__ import annotations

import argparse
import errno
import functools
import sys
import warnings
from collections.abc import Callable

from chpf.errors import ChpfError


def run_main(main: Callable[[list[str] | None], int]) -> Callable[[], None]:
    """Wrap ``main(argv) -> exit code`` for a console script: ChpfError -> one line, exit 2; a
    full disk (ENOSPC, EDQUOT) -> one line, exit 2; warnings print as one line each."""

    @functools.wraps(main)
    def cli() -> None:
        saved = warnings.formatwarning
        warnings.formatwarning = one_line_warning
        try:
            code = _exit_code(main)
        finally:
            warnings.formatwarning = saved  # as it was (cli() may run inside another program)
        sys.exit(code)

    return cli


def _exit_code(main: Callable[[list[str] | None], int]) -> int:
    """Run ``main(None)``; print a user-facing error as one line and return the exit code."""
    try:
        return main(None) or 0
    except ChpfError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(
            f"error: {where}{str(err.strerror).lower()} (disk full); free some space and rerun "
            "(finished outputs are kept)",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def one_line_warning(
    message: Warning | str, category: type[Warning], filename: str, lineno: int, line=None
) -> str:
    """``warnings.formatwarning`` of the console scripts: ``warning: <message>``, one line."""
    return f"warning: {message}\n"


def scene_list(text: str) -> list[int]:
    """argparse type of ``--scenes``: comma-separated scene ids ("48,49") -> [48, 49]."""
    try:
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated scene ids, got {text!r}"
        ) from None
