"""Session-wide test setup: puts the project root first on sys.path.

pytest's default ("prepend") import mode puts this folder on sys.path for this file, where the
test folders tests/chpf, tests/data_gen, ... would shadow the real packages of the same names;
the root in front of it keeps the real ones, and makes ``tests.helpers`` importable.
"""

from __future__ import annotations

import sys
from pathlib import Path

_ROOT = str(Path(__file__).resolve().parents[1])
if sys.path[:1] != [_ROOT]:
    sys.path.insert(0, _ROOT)
