"""The node's ``/diagnostics``: one status a period with its counters, its threads' state, the phase lock and the
last step's report (every key: msg_docs/topics.md); and, on the same timer, the process's housekeeping (the heap
given back to the system, an optional memory trace)."""
from __future__ import annotations

import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ..realtime import thread_scheduling
from .stepping import ms

#: The barrier contact's tool this far short of its command [m] warns (micrometres are the servo's own give).
TOOL_LAG_WARN = 1e-4


class Diagnostics:
    """Publishes the node's status (:meth:`publish`, the diagnostics timer's callback).

    Parameters
    ----------
    name : str
        The status's name (the node's fully qualified name + ``: simulation``).
    config : CurrentConfig
        The node's settings (frame, paused, lock-step).
    sim : Simulation
        Its method and parameters, bodies and time.
    clock : rclpy Clock
        Stamps the array; tells whether the node follows ``/clock`` (then the phase lock is off).
    stats : NodeStats
        The counters and the last step's report; its window starts again at each status.
    marker_worker : MarkerPublisher
        Its counts and niceness.
    markers_gil_free : bool
        Whether the markers are published without the GIL.
    phase_lock : PhaseLock or None
        Timer mode's phase lock (None: lock-step).
    publisher
        ``/diagnostics``'.
    heap_trimmer : HeapTrimmer
        Gives the heap back to the system before each status (its count and longest trim are reported).
    memory_trace : MemoryTrace or None
        Logs the allocations that grew, when asked for (``TISSUE_SIM_TRACEMALLOC``).
    """

    def __init__(self, name: str, config: Any, sim: Any, clock: Any, stats: Any, marker_worker: Any,
                 markers_gil_free: bool, phase_lock: Any, publisher: Any, heap_trimmer: Any,
                 memory_trace: Any = None) -> None:
        self.name, self.config, self.sim, self.clock, self.stats = name, config, sim, clock, stats
        self.marker_worker, self.markers_gil_free, self.phase_lock = marker_worker, markers_gil_free, phase_lock
        self.publisher, self.heap_trimmer, self.memory_trace = publisher, heap_trimmer, memory_trace

    def _phase_lock_values(self) -> dict[str, Any]:
        """The phase lock's state and measurements (msg_docs/topics.md)."""
        lock = self.phase_lock
        if lock is None:
            return {"phase_lock": "off"}
        st = lock.status
        return {"phase_lock": "off" if self.clock.ros_time_is_active else st.state,
                "phase_shifts": st.shifts, "phase_shift_total_ms": ms(st.shift_total_ns),
                "phase_shift_last_ms": ms(st.last_shift_ns), "pose_wait_median_ms": ms(st.wait_median_ns),
                "pose_jitter_ms": ms(st.jitter_ns), "pose_phase_concentration": st.concentration,
                "phase_samples": st.samples}

    def _counter_values(self, window: float) -> dict[str, Any]:
        s, w = self.stats, self.marker_worker
        return {
            "steps": s.steps,
            "step_rate_hz": s.window_steps / window,
            "step_time_mean_ms": 1e3 * s.window_step_time_sum / max(s.window_steps, 1),
            "step_time_max_ms": 1e3 * s.window_step_time_max,
            "sim_step_ms_mean": 1e3 * s.window_sim_time_sum / max(s.window_steps, 1),
            "overruns": s.overruns,
            "missed_ticks": s.missed_ticks,
            "divergences": s.divergences,
            "relocations": s.relocations,
            "unconverged_steps": s.unconverged_steps,
            "markers_published": w.published,
            "markers_skipped": w.skipped,
            "marker_encode_ms_mean": 1e3 * w.encode_seconds / max(w.published + w.errors, 1),
            "marker_thread_niceness": "unknown" if w.niceness is None else w.niceness,
            "step_thread_scheduling": thread_scheduling(),  # this timer runs on the step thread
            "markers_gil_free": self.markers_gil_free,
            "heap_trims": self.heap_trimmer.trims,
            "heap_trim_ms_max": 1e3 * self.heap_trimmer.seconds_max,
            **self._phase_lock_values(),
            **{f"dropped_{k}": v for k, v in s.dropped.items()},
        }

    def _report_values(self, r: Any) -> dict[str, Any]:
        """The last step's report (present once the node has stepped)."""
        sim = self.sim
        return {
            "in_contact": ",".join(str(bool(c)).lower() for c in r.in_contact),
            "d_star_m": ",".join(f"{d:.6g}" for d in r.d_star),
            "contact_particles": r.n_contact_particles,
            "residual": r.residual,
            "inverted_triangles": r.n_inverted,
            "energy_total": r.energy.scene_total,
            "energy_potential_j": r.energy.scene_potential,
            "material": sim.params.material,
            "tool_penetrating_particles": r.n_penetrating,
            "tool_penetration_depth_m": r.penetration_depth,
            "tool_tunnelled_particles": r.n_tunnelled,
            "tool_buried_in_tissue": r.tool_buried,
            "grasped_particles": int(r.grasped.size),
            "jaw_angle": "none" if sim.grasp.jaw is None else sim.grasp.jaw,
            "jaw_closed": sim.grasp.closed,
            "solve_iterations": r.solve_iterations,
            "solve_residual": r.solve_residual,
            "solve_converged": r.solve_converged,
            "tool_lag_m": r.tool_lag,
            "tool_lag_rad": r.tool_lag_angle,
            "energy_contact": float(r.energy.contact.sum()),
        }

    def _level(self, window: float, r: Any) -> tuple[int, str]:
        s, settings = self.stats, self.config.node
        level, message = DiagnosticStatus.OK, "paused" if settings.paused else "running"
        if s.window_steps and s.window_step_time_max > self.sim.params.dt:
            level, message = DiagnosticStatus.WARN, f"{message}; a step overran dt in the last {window:.1f} s"
        if r is not None and r.diverged:
            level, message = DiagnosticStatus.ERROR, f"{message}; the last step diverged (state restored)"
        if r is not None and not r.solve_converged and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, (f"{message}; the last step's solve stopped short "
                                                     f"(estimated error {r.solve_residual:.3g} > solve_tolerance)")
        if r is not None and r.tool_lag > TOOL_LAG_WARN and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, (f"{message}; the tool stopped {1e3 * r.tool_lag:.3g} mm short "
                                                     "of its command (the tissue cannot make room)")
        if r is not None and r.tool_buried and level == DiagnosticStatus.OK:
            level, message = DiagnosticStatus.WARN, f"{message}; the tool is buried in the tissue"
        return level, message

    def publish(self) -> None:
        """The diagnostics timer: one status with the counters and the last step's report (msg_docs/topics.md)."""
        now = time.monotonic()
        self.heap_trimmer.maybe_trim(now)
        if self.memory_trace is not None:
            self.memory_trace.maybe_report(now)
        s, sim, settings = self.stats, self.sim, self.config.node
        window = max(now - s.window_start, 1e-9)
        r = s.last_report
        values = {**self._counter_values(window), "paused": bool(settings.paused), "lock_step": settings.lock_step,
                  "method": sim.params.method, "scheme": sim.params.scheme, "iterations": sim.params.iterations,
                  "substeps": sim.params.substeps, "contact_model": sim.params.contact_model,
                  "bodies": ",".join(str(n).replace(",", " ") for n in sim.model.body_names), "sim_time_s": sim.time}
        if r is not None:
            values.update(self._report_values(r))
        level, message = self._level(window, r)
        status = DiagnosticStatus(level=level, name=self.name, message=message, hardware_id="tissue_sim",
                                  values=[KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v).lower()
                                                   if isinstance(v, bool) else str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.clock.now().to_msg()
        array.header.frame_id = settings.frame_id  # the frame of everything this node publishes (msg_docs/topics.md)
        self.publisher.publish(array)
        s.new_window(now)
