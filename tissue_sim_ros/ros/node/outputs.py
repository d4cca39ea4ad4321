"""The node's outputs: a step's messages, the markers and the rest mesh (``/diagnostics``: :mod:`.diagnostics`).

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
from typing import Any, Callable

import numpy as np
import rclpy

from ...core.contact.tool import ToolPose, ToolTwist
from ...core.sim.simulation import StepReport
from .. import messages, tool_applied
from ..marker_publisher import MarkerSnapshot
from .inputs import stamp_now


class Outputs:
    """Encodes and publishes what a step sends out, and the markers and points outside the steps.

    Parameters
    ----------
    config : CurrentConfig
        The node's settings (rates, frame, marker appearance), read at each step.
    sim : Simulation
        Its model and tool (the encoder), its state after each step.
    clock : rclpy Clock
        Stamps what goes out outside the steps (the rest mesh, a reset's state).
    publishers : NodePublishers
        One per output topic.
    marker_worker : MarkerPublisher
        Encodes and publishes the markers on its own thread.
    warnings : ThrottledWarnings
        Counts a message withheld for carrying NaN.
    lock_step : bool
        Lock-step: the markers go out at ``marker_rate`` by the wall clock (:meth:`flush_markers`), the newest
        state kept due; timer mode: every ``marker_rate`` steps.
    """

    def __init__(self, config: Any, sim: Any, clock: Any, publishers: Any, marker_worker: Any, warnings: Any,
                 lock_step: bool) -> None:
        self.config, self.sim, self.clock, self.publishers = config, sim, clock, publishers
        self.marker_worker, self.warnings, self.lock_step = marker_worker, warnings, lock_step
        self.encoder = self.make_encoder()
        self._steps_since_points = 0
        self._steps_since_markers = 0
        self._marker_due: MarkerSnapshot | None = None
        self._marker_sent = -math.inf

    def make_encoder(self) -> messages.StepEncoder:
        """The step encoder for the node's scene and its marker settings (rebuilt when those change)."""
        settings = self.config.node
        return messages.StepEncoder(
            self.sim.model, self.sim.tool, strain_color_max=settings.strain_color_max,
            wire_width=settings.wire_width, wireframe=settings.markers_wireframe)

    def publish(self, out: messages.StepMessages) -> None:
        for reason in out.withheld:
            self.warnings.drop("unpublished_nonfinite", reason)
        pubs = self.publishers.step_topics()
        for topic, data in out.messages.items():
            pubs[topic].publish(data)

    def every(self, rate: float) -> int:
        """Publish every this many steps for a rate [Hz] (at least every step)."""
        return max(1, int(round(1.0 / (self.sim.params.dt * rate))))

    # ------------------------------------------------------------------ a step

    def publish_step(self, stamp: tuple[int, int], report: StepReport, pose: ToolPose | None,
                     quaternion: tuple[float, float, float, float], twist: ToolTwist,
                     pose_stamp: tuple[int, int] = (0, 0)) -> None:
        """Everything one step sends out: its messages, its markers (when due) and, last, the tool it used
        (``pose_stamp``: the stamp of the pose message it used, which the tool marker carries)."""
        pubs = self.publishers
        self._publish_state(stamp, report, pose_stamp)
        # what this step used, for an exact offline replay (tool_applied.py); last, so that a step whose
        # applied tool is out (and recorded) has all its outputs out too (a signal waits for the whole step anyway)
        frame = self.config.node.frame_id
        if pose is not None:
            pubs.applied_pose.publish(tool_applied.encode_applied_pose(stamp, frame, pose.x, pose.y, quaternion))
        if self.encoder.grasper:  # the jaw the step used (before the twist: a step's applied tool ends with it)
            pubs.applied_jaw.publish(tool_applied.encode_applied_jaw(stamp, frame, self.sim.grasp.jaw))
        pubs.applied_twist.publish(tool_applied.encode_applied_twist(stamp, frame, twist))

    def _publish_state(self, stamp: tuple[int, int], report: StepReport, pose_stamp: tuple[int, int]) -> None:
        settings = self.config.node
        self._steps_since_points += 1
        self._steps_since_markers += 1
        publish_points = self._steps_since_points >= self.every(settings.points_rate)
        publish_markers = self._steps_since_markers >= self.every(settings.marker_rate)
        if publish_points:
            self._steps_since_points = 0
        if publish_markers:
            self._steps_since_markers = 0
        q = self.sim.state.particle_q
        self.publish(self.encoder.encode(stamp, settings.frame_id, report, q, points=publish_points, markers=False))
        if not np.isfinite(q).all():
            return
        if self.lock_step:
            # lock-step: poses come at any rate and may stop; markers at marker_rate by the clock, and the newest
            # state is kept due until the flush timer hands it over (the last pose's state is always shown)
            self._marker_due = self._marker_snapshot(stamp, report, q, pose_stamp)
            self.flush_markers()
        elif publish_markers:
            # encoded and published on the marker worker's thread, newest state only: never blocks the step
            self.marker_worker.submit(self._marker_snapshot(stamp, report, q, pose_stamp))

    def _marker_snapshot(self, stamp: tuple[int, int], report: StepReport, q: np.ndarray,
                         pose_stamp: tuple[int, int]) -> MarkerSnapshot:
        pose = self.sim.tool_pose
        contact = report.contact_particles
        return MarkerSnapshot(
            self.encoder.scene, stamp, self.config.node.frame_id, q.copy(),
            tool_pose=None if pose is None else (pose.x, pose.y, pose.yaw),
            tool_stamp=pose_stamp if pose is not None else None,
            contact_particles=None if contact is None else np.array(contact),
            grasped_particles=np.array(report.grasped))

    def flush_markers(self) -> None:
        """Lock-step: hand the newest unshown state to the marker worker if 1/marker_rate has passed since the last."""
        if self._marker_due is None:
            return
        now = time.monotonic()
        if now - self._marker_sent >= 1.0 / self.config.node.marker_rate:
            self.marker_worker.submit(self._marker_due)
            self._marker_due, self._marker_sent = None, now

    # ------------------------------------------------------------------ outside the steps

    def publish_rest_mesh(self) -> None:
        self.publishers.rest.publish(self.encoder.rest_markers(stamp_now(self.clock), self.config.node.frame_id,
                                                               self.sim.model))

    def publish_state_now(self) -> None:
        """Points and markers of the current state, outside the step cadence (after a reset)."""
        self.publish(self.encoder.state(stamp_now(self.clock), self.config.node.frame_id, self.sim.state.particle_q))


def marker_error(warnings: Any, context: Any) -> Callable[[Exception], None]:
    """What the marker thread does when it could not publish: a warning, unless the node is shutting down
    (SIGINT/SIGTERM: rcl then refuses the last array, which loses nothing a reader could still receive)."""

    def on_error(exc: Exception) -> None:
        if rclpy.ok(context=context):
            warnings.warn("markers", f"tissue/markers not published: {exc}")

    return on_error
