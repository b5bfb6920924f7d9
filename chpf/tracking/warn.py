"""The warning the filters give when a frame's weights are all zero or NaN."""

from __future__ import annotations

import warnings


class WeightCollapseWarning(RuntimeWarning):
    """All importance weights of a frame were zero or NaN: the filter reinvigorated fully."""


class CollapseWarner:
    """Warns once per filter (per run) on a weight collapse and counts the collapses."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.count = 0

    def collapse(self) -> None:
        """Record a collapsed frame; warn on the first one."""
        self.count += 1
        if self.count == 1:
            warnings.warn(
                f"{self.name}: all particle weights are zero or NaN; reinvigorating every "
                "particle from the candidate distribution (warned once per run)",
                WeightCollapseWarning,
                stacklevel=3,
            )
