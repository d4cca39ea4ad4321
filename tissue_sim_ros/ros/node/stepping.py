"""The node's stepping loop: the step timer (or lock-step), the phase lock, and the step itself.

Timer mode: a timer at 1/dt of the node's clock takes the tool messages
already received and steps with the newest valid pose. rcl keeps the timer
on its schedule and skips the ticks a late one missed; the loop counts them
(``missed_ticks``) and the steps that took longer than dt (``overruns``).
The phase lock (:mod:`tissue_sim_ros.core.timing.phase_lock`) moves the ticks
to just after the poses' arrivals. Lock-step: every accepted pose is one step
(:meth:`~tissue_sim_ros.ros.node.inputs.ToolInputs.take_pose` calls the ``step`` it was given,
:meth:`Stepper.step`), stamped with the pose's stamp. The flow is one way: the inputs hand the stepper their
tool, the stepper hands each step to the outputs.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from ...core.contact.tool import ToolTwist, twist_from_poses
from ...core.timing.phase_lock import PhaseLock
from ...core.timing.stamps import stamp_from_ns


def ms(ns: float) -> float:
    return ns * 1e-6


class Stepper:
    """Steps the simulation with the inputs' tool and hands each step to the outputs.

    Parameters
    ----------
    config : CurrentConfig
        The node's settings (``paused``, ``phase_lock``), read at each tick.
    sim : Simulation
        What is stepped.
    clock : rclpy Clock
        The node's clock (a tick's time, a step's stamp).
    stats, warnings
        Steps, overruns, missed ticks, divergences counted; the last report kept (``stats.last_report``).
    gate : OutputGate
        A step's outputs go out inside it, whole or not at all.
    outputs : Outputs
        Publishes each step.
    tool : callable
        ``tool(from_timer, stamp)``: the :class:`~.inputs.StepTool` a step uses (the inputs').
    take_inputs : callable
        Timer mode: takes the tool messages received before a tick (the inputs').
    phase_lock : PhaseLock or None
        Timer mode: moves the ticks to just after the poses' arrivals.
    logger
        The node's logger (the phase lock's shifts, at debug level).
    """

    def __init__(self, config: Any, sim: Any, clock: Any, stats: Any, warnings: Any, gate: Any, outputs: Any,
                 tool: Callable[[bool, tuple[int, int]], Any], take_inputs: Callable[[], None],
                 phase_lock: PhaseLock | None, logger: Any) -> None:
        self.config, self.sim, self.clock, self.stats, self.warnings = config, sim, clock, stats, warnings
        self.gate, self.outputs, self._tool, self._take_inputs = gate, outputs, tool, take_inputs
        self.phase_lock, self.logger = phase_lock, logger
        self.timer: Any = None
        self.period_ns: int | None = None
        self.last_tick: int | None = None
        """Scheduled time of the step timer's next call after the last tick [ns of the node clock]."""
        self._stretched = False
        """The timer's period is stretched by the phase lock for one interval (restored at the next tick)."""

    def use_timer(self, timer: Any) -> None:
        """Timer mode: step at ``timer``'s ticks (whose callback is :meth:`on_tick`), phase-locked to the poses."""
        self.timer = timer
        self.period_ns = timer.timer_period_ns

    def reset(self) -> None:
        """Forget the last tick (``~/reset``, a clock switch): the next one counts no missed ticks."""
        self.last_tick = None

    def forget_schedule(self) -> None:
        """The node's clock switched: the last tick and the poses' phase mean nothing on the new one."""
        self.last_tick = None
        if self.phase_lock is not None:
            self.phase_lock.reset()

    # ------------------------------------------------------------------ timer mode

    def on_tick(self) -> None:
        now = self.clock.now()
        # rcl keeps the timer on its schedule and, when a tick is late by more than a
        # period, skips the ticks missed; the next scheduled call tells how many it skipped
        next_call = now.nanoseconds + self.timer.time_until_next_call()
        if self.last_tick is not None:
            missed = int(round((next_call - self.last_tick) / self.timer.timer_period_ns)) - 1
            if missed > 0:
                self.stats.missed_ticks += missed
        self.last_tick = next_call
        self.steer_phase(next_call)
        if self.config.node.paused:
            return
        self._take_inputs()
        self.step(stamp_from_ns(now.nanoseconds), None, from_timer=True)

    def steer_phase(self, next_call: int) -> None:
        """Phase lock: move the timer's ticks to just after the poses' arrivals (core/timing/phase_lock.py).

        A shift s stretches one interval: the period is set to dt + s now, rcl
        computes the call after the next one from it, and the next tick puts dt
        back. Only on the system clock (arrivals are received times on it).
        """
        timer = self.timer
        period = timer.timer_period_ns
        if self._stretched:
            timer.timer_period_ns = self.period_ns
            self._stretched = False
        if self.phase_lock is None or self.clock.ros_time_is_active:
            return
        # this tick's scheduled time; with the parameter off the lock only measures (the wait on /diagnostics)
        shift = self.phase_lock.tick(next_call - period, steer=self.config.node.phase_lock)
        if shift:
            timer.timer_period_ns = self.period_ns + shift
            self._stretched = True
            st = self.phase_lock.status
            self.logger.debug(
                f"phase lock: ticks moved by {shift * 1e-6:+.2f} ms (median wait {ms(st.wait_median_ns):.2f} ms, "
                f"jitter {ms(st.jitter_ns):.2f} ms, concentration {st.concentration:.2f}, gain {ms(st.gain_ns):.2f} ms, "
                f"{st.shifts} shifts)")

    # ------------------------------------------------------------------ the step

    def step(self, stamp: tuple[int, int], twist: ToolTwist | None, from_timer: bool = False) -> None:
        """One simulation step and its messages; ``stamp`` stamps every output."""
        sim = self.sim
        t0 = time.perf_counter()
        tool = self._tool(from_timer, stamp)
        pose = tool.pose
        if from_timer:
            twist = tool.twist
        if pose is None:
            twist = ToolTwist()
        elif twist is None:
            # derived here, by the Simulation's own formula, so the twist used can be published and replayed
            twist = twist_from_poses(sim.tool_pose, pose, sim.params.dt)
        report = sim.step(pose, twist, jaw=tool.jaw)
        self._count(report)
        # whole or not at all: a signal ending the node waits for the step's last message (shutdown.py)
        with self.gate as open_:
            if open_:
                self.outputs.publish_step(stamp, report, pose, tool.quaternion, twist, tool.pose_stamp)
        elapsed = time.perf_counter() - t0
        s = self.stats
        s.count_step(elapsed, report.timings.get("total", 0.0))
        if elapsed > sim.params.dt:
            s.overruns += 1
            self.warnings.warn("overrun", f"step {report.step} took {elapsed * 1e3:.1f} ms > dt "
                                          f"{sim.params.dt * 1e3:.1f} ms ({s.overruns} overruns in {s.steps} steps)")

    def _count(self, report: Any) -> None:
        s = self.stats
        s.last_report = report
        s.steps += 1
        if report.diverged:
            s.divergences += 1
            self.warnings.warn("diverged", f"step {report.step}: the solver diverged; restored the last good state "
                                           f"({s.divergences} divergences so far)")
        if not report.solve_converged:
            s.unconverged_steps += 1
            self.warnings.warn("unconverged", f"step {report.step}: the material's solve stopped short of its own "
                                              f"step (estimated error {report.solve_residual:.3g} of the step > "
                                              f"solve_tolerance {self.sim.params.solve_tolerance:g} after "
                                              f"{report.solve_iterations} iterations): the tissue is softer or "
                                              f"stiffer than its material ({s.unconverged_steps} such steps in "
                                              f"{s.steps})")
