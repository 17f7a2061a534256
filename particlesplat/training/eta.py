"""The training progress bar's time left: the median of the recent steps' seconds times the steps left.

tqdm's own estimate is a smoothed mean of the rate over everything between two updates; a validation, a checkpoint
or a burst of load from another job then swings it by hours (75-94 h read on a 40,000-step recipe on a loaded
machine). The median of the last :data:`WINDOW` steps, each timed alone, is what a step costs now.
"""

from __future__ import annotations

import statistics
from collections import deque

WINDOW = 50  # recent steps the median is taken over


class StepTimes:
    """The wall seconds of the recent training steps (validation and checkpoints excluded)."""

    def __init__(self, window: int = WINDOW) -> None:
        self.times: deque[float] = deque(maxlen=window)

    def add(self, seconds: float) -> None:
        self.times.append(float(seconds))

    def median(self) -> float | None:
        """Median seconds a step over the window; None before the first step."""
        return statistics.median(self.times) if self.times else None

    def eta(self, steps_left: int) -> str:
        """``"1h02m"`` / ``"4m05s"`` / ``"12s"`` for ``steps_left`` steps at the median cost; ``"?"`` before the first
        step."""
        m = self.median()
        if m is None:
            return "?"
        return format_duration(m * max(steps_left, 0))


def format_duration(seconds: float) -> str:
    """Seconds as ``"2d03h"``, ``"1h02m"``, ``"4m05s"`` or ``"12s"`` (two units at most)."""
    s = int(round(seconds))
    days, s = divmod(s, 86400)
    hours, s = divmod(s, 3600)
    minutes, s = divmod(s, 60)
    if days:
        return f"{days}d{hours:02d}h"
    if hours:
        return f"{hours}h{minutes:02d}m"
    if minutes:
        return f"{minutes}m{s:02d}s"
    return f"{s}s"
