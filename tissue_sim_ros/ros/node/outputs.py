"""The node's outputs: a step's messages, the markers, the rest mesh and ``/diagnostics``.

A step's outputs (msg_docs/topics.md): the energy and its terms, the wrench,
the points at ``points_rate``, the markers at ``marker_rate`` (encoded and
published on the marker thread, newest state only) and, last, the tool the
step used (``tool/applied_pose``, ``tool/applied_twist``), all stamped with
the step's stamp. The messages are encoded by
:class:`~tissue_sim_ros.ros.messages.StepEncoder`, the one encoding
``tissue-sim replay`` writes too; a message that would carry NaN is withheld
and counted.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ...core.contact.tool import ToolPose, ToolTwist
from ...core.sim.simulation import StepReport
from .. import messages, tool_applied
from ..marker_publisher import MarkerSnapshot
from ..realtime import thread_scheduling
from .inputs import stamp_now
from .stepping import ms


class Outputs:
    """Encodes and publishes what the node sends out, on the publishers the node made (``pub_*``).

    Parameters
    ----------
    node : TissueSimNode
        Its publishers (looked up at each call: recording wraps them), simulation, typed settings, stats,
        warnings, marker worker and stepping loop (phase lock, lock-step or timer).
    """

    def __init__(self, node: Any) -> None:
        self.node = node
        self.encoder = self.make_encoder()
        self._steps_since_points = 0
        self._steps_since_markers = 0
        self._marker_due: MarkerSnapshot | None = None
        self._marker_sent = -math.inf

    def make_encoder(self) -> messages.StepEncoder:
        """The step encoder for the node's scene and its marker settings (rebuilt when those change)."""
        node, settings = self.node, self.node.config.node
        return messages.StepEncoder(
            node.sim.model, node.sim.tool, strain_color_max=settings.strain_color_max,
            wire_width=settings.wire_width, wireframe=settings.markers_wireframe)

    def publishers(self) -> dict[str, Any]:
        """The publisher of each step output (messages.STEP_TOPICS); looked up per call, as recording wraps them."""
        node = self.node
        return {"tissue/energy": node.pub_energy,
                **{f"tissue/energy/{k}": p for k, p in node.pub_energy_terms.items()},
                "tissue/energy/bodies": node.pub_energy_bodies, "tissue/contact": node.pub_contact,
                "tool/grasped": node.pub_grasped,
                "tool/wrench": node.pub_wrench,
                "tissue/points": node.pub_points, "tissue/markers": node.pub_markers}

    def publish(self, out: messages.StepMessages) -> None:
        for reason in out.withheld:
            self.node.warnings.drop("unpublished_nonfinite", reason)
        pubs = self.publishers()
        for topic, data in out.messages.items():
            pubs[topic].publish(data)

    def every(self, rate: float) -> int:
        """Publish every this many steps for a rate [Hz] (at least every step)."""
        return max(1, int(round(1.0 / (self.node.sim.params.dt * rate))))

    # ------------------------------------------------------------------ a step

    def publish_step(self, stamp: tuple[int, int], report: StepReport, pose: ToolPose | None,
                     quaternion: tuple[float, float, float, float], twist: ToolTwist) -> None:
        """Everything one step sends out: its messages, its markers (when due) and, last, the tool it used."""
        node = self.node
        self._publish_state(stamp, report)
        # what this step used, for an exact offline replay (tool_applied.py); last, so that a step whose
        # applied tool is out (and recorded) has all its outputs out too (a signal waits for the whole step anyway)
        frame = node.frame_id
        if pose is not None:
            node.pub_applied_pose.publish(tool_applied.encode_applied_pose(stamp, frame, pose.x, pose.y, quaternion))
        if self.encoder.grasper:  # the jaw the step used (before the twist: a step's applied tool ends with it)
            node.pub_applied_jaw.publish(tool_applied.encode_applied_jaw(stamp, frame, node.sim.grasp.jaw))
        node.pub_applied_twist.publish(tool_applied.encode_applied_twist(stamp, frame, twist))

    def _publish_state(self, stamp: tuple[int, int], report: StepReport) -> None:
        node, settings = self.node, self.node.config.node
        self._steps_since_points += 1
        self._steps_since_markers += 1
        publish_points = self._steps_since_points >= self.every(settings.points_rate)
        publish_markers = self._steps_since_markers >= self.every(settings.marker_rate)
        if publish_points:
            self._steps_since_points = 0
        if publish_markers:
            self._steps_since_markers = 0
        q = node.sim.state.particle_q
        self.publish(self.encoder.encode(stamp, node.frame_id, report, q, points=publish_points, markers=False))
        if not np.isfinite(q).all():
            return
        if node.step_timer is None:
            # lock-step: poses come at any rate and may stop; markers at marker_rate by the clock, and the newest
            # state is kept due until the flush timer hands it over (the last pose's state is always shown)
            self._marker_due = self._marker_snapshot(stamp, report, q)
            self.flush_markers()
        elif publish_markers:
            # encoded and published on the marker worker's thread, newest state only: never blocks the step
            node.marker_worker.submit(self._marker_snapshot(stamp, report, q))

    def _marker_snapshot(self, stamp: tuple[int, int], report: StepReport, q: np.ndarray) -> MarkerSnapshot:
        node = self.node
        pose = node.sim.tool_pose
        contact = report.contact_particles
        return MarkerSnapshot(
            self.encoder.scene, stamp, node.frame_id, q.copy(),
            tool_pose=None if pose is None else (pose.x, pose.y, pose.yaw),
            tool_stamp=node.inputs.tool.pose_stamp if pose is not None else None,
            contact_particles=None if contact is None else np.array(contact),
            grasped_particles=np.array(report.grasped))

    def flush_markers(self) -> None:
        """Lock-step: hand the newest unshown state to the marker worker if 1/marker_rate has passed since the last."""
        if self._marker_due is None:
            return
        now = time.monotonic()
        if now - self._marker_sent >= 1.0 / self.node.config.node.marker_rate:
            self.node.marker_worker.submit(self._marker_due)
            self._marker_due, self._marker_sent = None, now

    def marker_error(self, exc: Exception) -> None:
        """The marker thread could not publish: a warning, unless the node is shutting down (SIGINT/SIGTERM: rcl
        then refuses the last array, which loses nothing a reader could still receive)."""
        if rclpy.ok(context=self.node.context):
            self.node.warnings.warn("markers", f"tissue/markers not published: {exc}")

    # ------------------------------------------------------------------ outside the steps

    def publish_rest_mesh(self) -> None:
        node = self.node
        node.pub_rest.publish(self.encoder.rest_markers(stamp_now(node), node.frame_id, node.sim.model))

    def publish_state_now(self) -> None:
        """Points and markers of the current state, outside the step cadence (after a reset)."""
        node = self.node
        self.publish(self.encoder.state(stamp_now(node), node.frame_id, node.sim.state.particle_q))

    # ------------------------------------------------------------------ /diagnostics

    def _phase_lock_values(self) -> dict[str, Any]:
        """The phase lock's state and measurements for /diagnostics (msg_docs/topics.md)."""
        lock = self.node.stepping.phase_lock
        if lock is None:
            return {"phase_lock": "off"}
        st = lock.status
        return {"phase_lock": "off" if self.node.get_clock().ros_time_is_active else st.state,
                "phase_shifts": st.shifts, "phase_shift_total_ms": ms(st.shift_total_ns),
                "phase_shift_last_ms": ms(st.last_shift_ns), "pose_wait_median_ms": ms(st.wait_median_ns),
                "pose_jitter_ms": ms(st.jitter_ns), "pose_phase_concentration": st.concentration,
                "phase_samples": st.samples}

    def publish_diagnostics(self) -> None:
        """The diagnostics timer: one status with the counters and the last step's report (msg_docs/topics.md)."""
        node = self.node
        s, w, sim = node.stats, node.marker_worker, node.sim
        now = time.monotonic()
        node.heap_trimmer.maybe_trim(now)
        if node.memory_trace is not None:
            node.memory_trace.maybe_report(now)
        window = max(now - s.window_start, 1e-9)
        r = node.last_report
        level = DiagnosticStatus.OK
        message = "paused" if node.paused else "running"
        if s.window_steps and s.window_step_time_max > sim.params.dt:
            level, message = DiagnosticStatus.WARN, f"{message}; a step overran dt in the last {window:.1f} s"
        if r is not None and r.diverged:
            level, message = DiagnosticStatus.ERROR, f"{message}; the last step diverged (state restored)"
        values = {
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
            "markers_gil_free": node.pub_markers.gil_free,
            "heap_trims": node.heap_trimmer.trims,
            "heap_trim_ms_max": 1e3 * node.heap_trimmer.seconds_max,
            **self._phase_lock_values(),
            **{f"dropped_{k}": v for k, v in s.dropped.items()},
            "paused": node.paused,
            "lock_step": node.config.node.lock_step,
            "method": sim.params.method,
            "scheme": sim.params.scheme,
            "iterations": sim.params.iterations,
            "substeps": sim.params.substeps,
            "contact_model": sim.params.contact_model,
            "bodies": ",".join(str(n).replace(",", " ") for n in sim.model.body_names),
            "sim_time_s": sim.time,
        }
        if r is not None:
            values.update({
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
            })
            if not r.solve_converged and level == DiagnosticStatus.OK:
                level, message = DiagnosticStatus.WARN, (f"{message}; the last step's solve stopped short "
                                                         f"(estimated error {r.solve_residual:.3g} > solve_tolerance)")
            if r.tool_buried and level == DiagnosticStatus.OK:
                level, message = DiagnosticStatus.WARN, f"{message}; the tool is buried in the tissue"
        status = DiagnosticStatus(level=level, name=f"{node.get_fully_qualified_name()}: simulation",
                                  message=message, hardware_id="tissue_sim",
                                  values=[KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v).lower()
                                                   if isinstance(v, bool) else str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = node.get_clock().now().to_msg()
        array.header.frame_id = node.frame_id  # the frame of everything this node publishes (msg_docs/topics.md)
        node.pub_diagnostics.publish(array)
        s.window_steps, s.window_step_time_sum, s.window_step_time_max, s.window_start = 0, 0.0, 0.0, now
        s.window_sim_time_sum = 0.0
