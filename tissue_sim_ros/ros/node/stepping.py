"""The node's stepping loop: the step timer (or lock-step), the phase lock, and the step itself.

Timer mode: a timer at 1/dt of the node's clock takes the tool messages
already received and steps with the newest valid pose. rcl keeps the timer
on its schedule and skips the ticks a late one missed; the loop counts them
(``missed_ticks``) and the steps that took longer than dt (``overruns``).
The phase lock (:mod:`tissue_sim_ros.core.timing.phase_lock`) moves the ticks
to just after the poses' arrivals. Lock-step: every accepted pose is one step
(:meth:`~tissue_sim_ros.ros.node.inputs.ToolInputs.take_pose` calls
:meth:`Stepper.step`), stamped with the pose's stamp.
"""
from __future__ import annotations

import time
from typing import Any

from ...core.contact.tool import ToolTwist, twist_from_poses
from ...core.timing.phase_lock import PhaseLock
from ...core.timing.stamps import stamp_from_ns


def ms(ns: float) -> float:
    return ns * 1e-6


class Stepper:
    """Steps the node's simulation and hands each step to the outputs.

    Parameters
    ----------
    node : TissueSimNode
        Its simulation (``sim``), clock, stats, warnings, tool inputs and outputs.
    """

    def __init__(self, node: Any) -> None:
        self.node = node
        self.timer: Any = None
        self.period_ns: int | None = None
        self.phase_lock: PhaseLock | None = None
        self.last_tick: int | None = None
        """Scheduled time of the step timer's next call after the last tick [ns of the node clock]."""
        self._stretched = False
        """The timer's period is stretched by the phase lock for one interval (restored at the next tick)."""

    def use_timer(self, timer: Any) -> None:
        """Timer mode: step at ``timer``'s ticks (whose callback is :meth:`on_tick`), phase-locked to the poses."""
        self.timer = timer
        self.period_ns = timer.timer_period_ns
        self.phase_lock = PhaseLock(self.period_ns)

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
        node = self.node
        now = node.get_clock().now()
        # rcl keeps the timer on its schedule and, when a tick is late by more than a
        # period, skips the ticks missed; the next scheduled call tells how many it skipped
        next_call = now.nanoseconds + self.timer.time_until_next_call()
        if self.last_tick is not None:
            missed = int(round((next_call - self.last_tick) / self.timer.timer_period_ns)) - 1
            if missed > 0:
                node.stats.missed_ticks += missed
        self.last_tick = next_call
        self.steer_phase(next_call)
        if node.paused:
            return
        node.inputs.take_queued()
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
        if self.node.get_clock().ros_time_is_active:
            return
        # this tick's scheduled time; with the parameter off the lock only measures (the wait on /diagnostics)
        shift = self.phase_lock.tick(next_call - period, steer=self.node.config.node.phase_lock)
        if shift:
            timer.timer_period_ns = self.period_ns + shift
            self._stretched = True
            st = self.phase_lock.status
            self.node.get_logger().debug(
                f"phase lock: ticks moved by {shift * 1e-6:+.2f} ms (median wait {ms(st.wait_median_ns):.2f} ms, "
                f"jitter {ms(st.jitter_ns):.2f} ms, concentration {st.concentration:.2f}, gain {ms(st.gain_ns):.2f} ms, "
                f"{st.shifts} shifts)")

    # ------------------------------------------------------------------ the step

    def step(self, stamp: tuple[int, int], twist: ToolTwist | None, from_timer: bool = False) -> None:
        """One simulation step and its messages; ``stamp`` stamps every output."""
        node = self.node
        sim = node.sim
        t0 = time.perf_counter()
        if from_timer:
            pose, twist = node.inputs.tool_for_step()
        else:
            pose = node.inputs.tool.pose
        if pose is None:
            twist = ToolTwist()
        elif twist is None:
            # derived here, by the Simulation's own formula, so the twist used can be published and replayed
            twist = twist_from_poses(sim.tool_pose, pose, sim.params.dt)
        quaternion = node.inputs.tool.quaternion
        # the jaw: the newest (timer mode), or the one of the pose's time (lock-step, as twists are paired)
        jaw = node.inputs.tool.jaw if from_timer else node.inputs.tool.jaw_at(stamp)
        report = sim.step(pose, twist, jaw=jaw)
        node.last_report = report
        s = node.stats
        s.steps += 1
        if report.diverged:
            s.divergences += 1
            node.warnings.warn("diverged", f"step {report.step}: the solver diverged; restored the last good state "
                                           f"({s.divergences} divergences so far)")
        if not report.solve_converged:
            s.unconverged_steps += 1
            node.warnings.warn("unconverged", f"step {report.step}: the material's solve stopped short of its own "
                                              f"step (estimated error {report.solve_residual:.3g} of the step > "
                                              f"solve_tolerance {sim.params.solve_tolerance:g} after "
                                              f"{report.solve_iterations} iterations): the tissue is softer or "
                                              f"stiffer than its material ({s.unconverged_steps} such steps in "
                                              f"{s.steps})")
        # whole or not at all: a signal ending the node waits for the step's last message (shutdown.py)
        with node.output_gate as open_:
            if open_:
                node.outputs.publish_step(stamp, report, pose, quaternion, twist)
        elapsed = time.perf_counter() - t0
        s.window_steps += 1
        s.window_step_time_sum += elapsed
        s.window_step_time_max = max(s.window_step_time_max, elapsed)
        s.window_sim_time_sum += report.timings.get("total", 0.0)
        if elapsed > sim.params.dt:
            s.overruns += 1
            node.warnings.warn("overrun", f"step {report.step} took {elapsed * 1e3:.1f} ms > dt "
                                          f"{sim.params.dt * 1e3:.1f} ms ({s.overruns} overruns in {s.steps} steps)")
