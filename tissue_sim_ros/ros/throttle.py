"""What the nodes log about bad input: each kind of warning at most once per period, dropped messages counted by
kind (``tissue_sim_node``'s ``dropped`` counts and ``tissue_controller``'s ``dropped_*``, both on /diagnostics)."""
from __future__ import annotations

import math
import time
from typing import Any, Callable


class ThrottledWarnings:
    """Warnings logged at most once per ``period()`` [s] for each kind; dropped messages counted in ``counts``.

    Parameters
    ----------
    logger
        An rclpy logger.
    counts : dict
        Kind -> dropped messages so far (shared: the node reports it).
    period : callable
        The period, read at each warning (a node's parameter changed at run time applies at once).
    """

    def __init__(self, logger: Any, counts: dict[str, int], period: Callable[[], float]) -> None:
        self.logger, self.counts, self.period = logger, counts, period
        self._last: dict[str, float] = {}

    def warn(self, kind: str, message: str) -> None:
        """Log a warning at most once per period for each kind."""
        now = time.monotonic()
        if now - self._last.get(kind, -math.inf) >= self.period():
            self._last[kind] = now
            self.logger.warning(message)

    def drop(self, kind: str, message: str) -> None:
        """Count a dropped message of ``kind`` (a key of ``counts``) and warn, throttled."""
        self.counts[kind] += 1
        self.warn(kind, f"dropped: {message} ({self.counts[kind]} dropped so far)")
