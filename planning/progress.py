"""Progress callbacks shared by the stages: ``progress(fraction in [0, 1], message)``.

:class:`Throttled` passes a stage's reports on at most about ten times a second, the fraction never
going back; the paths stage, the finishing passes, the guard and the tri-dexel kernels report through
it. It uses no stage (the ``geometry`` rule)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

Progress = Callable[[float, str], None]


class Throttled:
    """``progress`` passed on at most once per ``min_interval_s`` (the first call, a ``force``d one and
    the first with fraction 1.0 always), the fraction clipped to [0, 1] and never going back. A None
    ``progress`` makes every call a no-op."""

    def __init__(self, progress: Progress | None, min_interval_s: float = 0.1):
        self.progress = progress
        self.min_interval_s = float(min_interval_s)
        self.last_t = -math.inf
        self.last_f = 0.0

    def __call__(self, fraction: float, message: str, force: bool = False) -> None:
        if self.progress is None:
            return
        f = max(self.last_f, min(1.0, max(0.0, float(fraction))))
        now = time.monotonic()
        if not force and f < 1.0 and now - self.last_t < self.min_interval_s:
            return
        if not force and f >= 1.0 and self.last_f >= 1.0:
            return
        self.last_t, self.last_f = now, f
        self.progress(f, message)

    def part(self, lo: float, hi: float) -> Progress:
        """A callback mapping [0, 1] onto [lo, hi] of this one (same throttle)."""
        return lambda f, msg: self(lo + (hi - lo) * min(1.0, max(0.0, float(f))), msg)
