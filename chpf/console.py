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
        warnings.formatwarning = one_line_warning
        try:
            code = main(None)
        except ChpfError as err:
            print(f"error: {err}", file=sys.stderr)
            sys.exit(2)
        except OSError as err:
            if err.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            where = f"{err.filename}: " if err.filename else ""
            print(
                f"error: {where}{str(err.strerror).lower()} (disk full); free some space and "
                "rerun (finished outputs are kept)",
                file=sys.stderr,
            )
            sys.exit(2)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            sys.exit(130)
        sys.exit(code or 0)

    return cli


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
