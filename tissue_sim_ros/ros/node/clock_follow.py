"""A timer-mode node that follows ``/clock`` while someone publishes it (``follow_clock``, default on).

``tissue-sim play BAG`` publishes ``/clock`` with the bag's time by default. A
node started without ``use_sim_time`` would take the bag's tool poses, stamped
when they were recorded, as stale and drop every one. With ``follow_clock``
the node notices a ``/clock`` publisher (checked every 0.1 s of wall time),
turns ``use_sim_time`` on, so its step timer and its stamp checks run on the
bag's time, and turns it off again once no ``/clock`` publisher has been seen
for 1 s: then it is back on the system clock, for a live robot. A node
started with ``use_sim_time:=true`` is left alone. Each switch forgets the
last input stamps (the two clocks are years apart, so the next pose would
look out of order or stale); the simulation state stays.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from rclpy.clock import Clock, ClockType

CHECK_PERIOD = 0.1
"""Seconds of wall time between looks at the graph."""
GONE_AFTER = 1.0
"""Seconds without a /clock publisher before the node goes back to the system clock."""


class ClockFollower:
    """Switches ``use_sim_time`` on while ``/clock`` has a publisher (only if the node switched it on itself).

    Parameters
    ----------
    clock_publishers : callable
        How many publishers ``/clock`` has now (the node's ``count_publishers`` of its resolved name).
    use_sim_time : callable
        ``use_sim_time()`` reads the node's parameter, ``use_sim_time(on)`` sets it.
    on_switch : callable
        Called with True (now following /clock) or False (back on the system clock) after each switch.
    create_timer : callable
        The node's ``create_timer``: the look at the graph runs on a wall-clock timer.
    """

    def __init__(self, clock_publishers: Callable[[], int], use_sim_time: Callable[..., bool],
                 on_switch: Callable[[bool], None], create_timer: Callable[..., Any]) -> None:
        self._publishers = clock_publishers
        self._use_sim_time = use_sim_time
        self._on_switch = on_switch
        self.following = False
        self.switches = 0
        self._gone_since: float | None = None
        # wall-clock timer: a node on a /clock that stopped must still notice that it stopped
        self.timer = create_timer(CHECK_PERIOD, self._check, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _set(self, on: bool) -> None:
        self._use_sim_time(on)
        self.following = on
        self.switches += 1
        self._on_switch(on)

    def _check(self) -> None:
        publishers = self._publishers()
        if not self.following:
            if publishers > 0 and not self._use_sim_time():
                self._set(True)
            return
        if publishers > 0:
            self._gone_since = None
            return
        now = time.monotonic()
        if self._gone_since is None:
            self._gone_since = now
        elif now - self._gone_since >= GONE_AFTER:
            self._gone_since = None
            self._set(False)
