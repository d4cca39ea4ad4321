"""The node's counters on ``/diagnostics``, which the inputs, the stepping loop and the outputs all count into (the
throttled warnings that count drops: :class:`~tissue_sim_ros.ros.throttle.ThrottledWarnings`), and the last step's
report."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class NodeStats:
    """Counters reported on /diagnostics (cumulative since start)."""

    steps: int = 0
    overruns: int = 0
    """Steps whose processing (step + publishing) took longer than dt of wall time."""
    missed_ticks: int = 0
    """Timer ticks skipped because the previous one ran late."""
    divergences: int = 0
    relocations: int = 0
    """Streams of poses far from the tool taken up (a relocated robot; ``relocate_poses``)."""
    unconverged_steps: int = 0
    """Material steps whose solve stopped short of solve_tolerance (StepReport.solve_converged False)."""
    dropped: dict[str, int] = field(default_factory=lambda: {
        "nonfinite": 0, "frame": 0, "stale": 0, "future": 0, "out_of_order": 0, "tool_jump": 0,
        "unpublished_nonfinite": 0, "jaw_empty": 0})
    window_steps: int = 0
    window_step_time_sum: float = 0.0
    window_step_time_max: float = 0.0
    window_sim_time_sum: float = 0.0
    """Wall time inside Simulation.step (contact + solve + energy) over the window [s]."""
    window_start: float = field(default_factory=time.monotonic)
    last_report: Any = None
    """The last step's :class:`~tissue_sim_ros.core.sim.simulation.StepReport` (None before the first)."""

    def count_step(self, elapsed: float, sim_seconds: float) -> None:
        """A step's wall time (step and outputs) and the simulation's own share of it, into the window [s]."""
        self.window_steps += 1
        self.window_step_time_sum += elapsed
        self.window_step_time_max = max(self.window_step_time_max, elapsed)
        self.window_sim_time_sum += sim_seconds

    def new_window(self, now: float) -> None:
        self.window_steps, self.window_step_time_sum, self.window_step_time_max = 0, 0.0, 0.0
        self.window_sim_time_sum, self.window_start = 0.0, now
