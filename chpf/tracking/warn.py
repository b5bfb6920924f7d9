"""Warnings given once per run: weight collapses, invalid detection boxes, missing depth,
unreadable frames."""

from __future__ import annotations

import warnings


class WeightCollapseWarning(RuntimeWarning):
    """All importance weights of a frame were zero or NaN: the filter reinvigorated fully."""


class InvalidBoxWarning(UserWarning):
    """A detection box was not 4 finite numbers with positive width and height: the frame was
    tracked without a box (predict only)."""


class MissingDepthWarning(UserWarning):
    """A frame of an RGB-D run had no depth image: it was tracked with RGB only."""


class SkippedFrameWarning(UserWarning):
    """A frame could not be read (a corrupt image, a video that ends early): it was skipped and
    the run went on."""


class OnceWarner:
    """Warns on the first event of a kind (per run) and counts them all."""

    def __init__(self, category: type[Warning]) -> None:
        self.category = category
        self.count = 0

    def warn(self, message: str) -> None:
        """Record an event; warn with ``message`` on the first one."""
        self.count += 1
        if self.count == 1:
            warnings.warn(f"{message} (warned once per run)", self.category, stacklevel=3)


class CollapseWarner(OnceWarner):
    """Warns once per filter (per run) on a weight collapse and counts the collapses."""

    def __init__(self, name: str) -> None:
        super().__init__(WeightCollapseWarning)
        self.name = name

    def collapse(self) -> None:
        """Record a collapsed frame; warn on the first one."""
        self.warn(
            f"{self.name}: all particle weights are zero or NaN; reinvigorating every particle "
            "from the candidate distribution"
        )
