"""Phase lock: put a fixed-rate timer's ticks just after the arrivals of a periodic input stream.

In timer mode the node steps on its own 1/dt timer with the newest tool pose.
A robot publishing its poses at the same rate but at another phase makes every
pose wait for the node's next tick: between 0 and one period, fixed for a run by
that phase (up to 10 ms at 100 Hz, on top of the step). This estimator watches
when the poses arrive relative to the ticks and tells the timer how far to move
its ticks so that they fall just after the arrivals, with a margin for the
arrivals' jitter. It has no clock and no ROS: arrival and tick times (integer
nanoseconds of one clock) go in, a shift comes out, so it is tested on
synthetic arrival times.

How it decides (every ``eval_ticks`` ticks, once ``min_samples`` recent arrivals
are in the window of the last ``window``):

* each arrival's phase relative to the ticks, ``(a - tick) mod period``;
* the cost of a tick phase: the mean wait the window's poses would have had
  with the ticks there, each arrival counted ``guard`` late (a pose arriving
  just before a tick may miss it and wait a whole period). Its minimum is just
  after one of the arrivals: for a stream with jitter, after most of the
  cluster; a late outlier costs a period once, not every pose;
* hysteresis: the ticks move only when the best phase would cut the mean wait
  by more than ``gain_out`` (``gain_in`` while still moving toward it), each
  shift at most ``max_shift`` (the timer's interval is stretched or shortened
  once by it); after a shift the estimator waits ``hold_ticks`` ticks for the
  timer to take it;
* a stream whose phases do not cluster is left alone (``irregular``): random
  arrivals, or a rate unrelated to the timer's (30 or 200 Hz against 100 Hz),
  for which no phase is better and the best one found in a window would be
  noise. The measure is the phases' mean resultant length (1 for one phase,
  ~1/sqrt(n) for n random ones; 0.92 for a 2 ms Gaussian jitter at 100 Hz),
  which must reach ``min_concentration``.

Its figures, for /diagnostics: the median wait from arrival to the next tick
and the 10-90 % spread (jitter) of the arrival phases, unwrapped around their
circular mean (a stream arriving right at the ticks is one cluster, not two).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

STATES = ("collecting", "irregular", "locking", "locked", "no stream", "measuring")


@dataclass
class PhaseLockStatus:
    """What the lock measured and decided (reported on /diagnostics)."""

    state: str = "collecting"
    """collecting (too few recent arrivals), locking (moving the ticks), locked (no better phase), irregular
    (scattered arrivals: no better phase), no stream, measuring (not steering)."""
    shifts: int = 0
    """Shifts made since start."""
    shift_total_ns: int = 0
    """Sum of the shifts' magnitudes [ns]."""
    last_shift_ns: int = 0
    wait_median_ns: float = math.nan
    """Median wait from a pose's arrival to the next tick, measured against the ticks at the last evaluation [ns]."""
    jitter_ns: float = math.nan
    """10th to 90th percentile spread of the arrival phases [ns]."""
    samples: int = 0
    concentration: float = math.nan
    """Mean resultant length of the arrival phases (1: one phase; ~0.1 random)."""
    gain_ns: float = math.nan
    """How much the mean wait would fall with the ticks at the best phase, at the last evaluation [ns]."""


class PhaseLock:
    """Estimate the phase of an input stream against a timer's ticks; say how far to move the ticks.

    Parameters
    ----------
    period_ns : int
        The timer's period [ns].
    window : int
        Arrivals kept (the newest).
    min_samples : int
        Recent arrivals needed before any decision.
    guard_ns : int
        An arrival is counted this much later [ns]: the margin kept between the arrivals and the ticks.
    gain_in_ns, gain_out_ns : int
        Hysteresis: the ticks move while the best phase cuts the mean wait by more than gain_in [ns];
        once there, only when it would cut it by more than gain_out.
    max_shift_ns : int
        Largest shift per correction [ns].
    hold_ticks : int
        Ticks to wait after a shift.
    eval_ticks : int
        Evaluate every this many ticks.
    min_concentration : float
        Mean resultant length of the arrival phases (1: all at one phase; ~1/sqrt(window) for random
        arrivals) below which the stream is irregular and the ticks are left alone.
    stale_periods : int
        Arrivals older than this many periods before a tick are forgotten.
    """

    def __init__(self, period_ns: int, window: int = 128, min_samples: int = 48, guard_ns: int = 500_000,
                 gain_in_ns: int = 300_000, gain_out_ns: int = 1_000_000, max_shift_ns: int = 2_000_000,
                 hold_ticks: int = 20, eval_ticks: int = 10, min_concentration: float = 0.5,
                 stale_periods: int = 200) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns={period_ns}: expected > 0")
        if not 0 < max_shift_ns < period_ns // 2:
            raise ValueError(f"max_shift_ns={max_shift_ns}: expected in (0, period/2)")
        self.period_ns = int(period_ns)
        self.min_samples = min_samples
        self.guard_ns = guard_ns
        self.gain_in_ns = gain_in_ns
        self.gain_out_ns = gain_out_ns
        self.max_shift_ns = max_shift_ns
        self.hold_ticks = hold_ticks
        self.eval_ticks = eval_ticks
        self.min_concentration = min_concentration
        self.stale_ns = stale_periods * period_ns
        self._arrivals: deque[int] = deque(maxlen=window)
        self._hold = 0
        self._countdown = 0
        self._locked = False
        self.status = PhaseLockStatus()

    def arrival(self, t_ns: int) -> None:
        """A message of the stream arrived at ``t_ns``."""
        self._arrivals.append(int(t_ns))

    def reset(self) -> None:
        """Forget the arrivals (the clock changed); the counters stay."""
        self._arrivals.clear()
        self._locked = False
        self._hold = self._countdown = 0
        self.status.state = "collecting"

    def tick(self, scheduled_ns: int, steer: bool = True) -> int:
        """The timer ticked at its scheduled time ``scheduled_ns``: the shift [ns] to move the later ticks by.

        Positive: later. 0: leave the ticks where they are. The caller moves the
        schedule (e.g. stretches the timer's next interval by the shift); the
        ticks passed in afterwards must be the moved ones. ``steer=False``:
        measure only (status: state ``measuring``), never shift.
        """
        if self._hold > 0:
            self._hold -= 1
            return 0
        if self._countdown > 0:
            self._countdown -= 1
            return 0
        self._countdown = self.eval_ticks - 1
        st = self.status
        while self._arrivals and self._arrivals[0] < scheduled_ns - self.stale_ns:
            self._arrivals.popleft()
        st.samples = len(self._arrivals)
        if not self._arrivals:
            st.state = "no stream"
            self._locked = False
            return 0
        if len(self._arrivals) < self.min_samples:
            st.state = "collecting"
            return 0
        p = self.period_ns
        # relative to the newest arrival first: small integers, exact in float64
        ref = self._arrivals[-1]
        phase = (np.array(self._arrivals, dtype=np.int64) - ref + (ref - scheduled_ns) % p) % p
        phase = phase.astype(np.float64)
        n = len(phase)
        angle = phase * (2.0 * math.pi / p)
        c, s = float(np.cos(angle).mean()), float(np.sin(angle).mean())
        centre = math.atan2(s, c) * p / (2.0 * math.pi)
        # mean resultant length: 1 for arrivals at one phase, ~1/sqrt(n) for random ones
        st.concentration = math.hypot(c, s)
        # unwrapped around the centre: (centre - p/2, centre + p/2]
        unwrapped = centre + (phase - centre + p / 2.0) % p - p / 2.0
        unwrapped.sort()
        lo, hi = unwrapped[n // 10], unwrapped[(9 * n) // 10]
        st.jitter_ns = float(hi - lo)
        # wait from each arrival to the next tick (ticks at multiples of p from scheduled_ns)
        wait = (-phase) % p
        wait.sort()
        st.wait_median_ns = float(wait[n // 2])
        if not steer:
            st.state = "measuring"
            self._locked = False
            return 0
        if st.concentration < self.min_concentration:
            # random arrivals or a rate unrelated to the timer's: any phase is as good (the best found
            # in a window of random arrivals is noise)
            self._locked = False
            st.state = "irregular"
            return 0
        # the mean wait of the window's poses if the ticks were at phase psi (relative to scheduled_ns),
        # each arrival counted guard_ns late (one that close before a tick may miss it):
        #     cost(psi) = guard + mean_i ((psi - phase_i - guard) mod p)
        # rises linearly between arrivals and drops by p at each, so its minimum is at one of psi = phase_k + guard
        # with l = (phase + guard) mod p sorted, cost(l_k) = guard + mean_i ((l_k - l_i) mod p)
        #     = guard + l_k - mean(l) + p (n - 1 - k) / n   (the arrivals after l_k wrap to the next tick)
        late = (phase + self.guard_ns) % p
        late.sort()
        cost_now = float(np.mean((-late) % p))
        costs = late - late.mean() + p * (n - 1 - np.arange(n)) / n
        best = int(np.argmin(costs))
        gain = cost_now - float(costs[best])
        st.gain_ns = gain
        if gain <= (self.gain_out_ns if self._locked else self.gain_in_ns):
            self._locked = True
            st.state = "locked"
            return 0
        self._locked = False
        error = (float(late[best]) + p / 2.0) % p - p / 2.0  # in [-p/2, p/2): move the ticks by this
        shift = int(round(max(-self.max_shift_ns, min(self.max_shift_ns, error))))
        st.state = "locking"
        st.shifts += 1
        st.shift_total_ns += abs(shift)
        st.last_shift_ns = shift
        self._hold = self.hold_ticks
        return shift
