"""TissueSimNode: tool pose in, tissue, energy and reaction out, at a fixed rate.

Run it::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml

Every topic, frame, unit, QoS, parameter and service is described in
``msg_docs/``. The node converts messages and calls the library
(:class:`~tissue_sim_ros.core.sim.simulation.Simulation`); all physics lives there.

Timing: a timer at 1/dt of the node's clock (``use_sim_time`` honoured) steps
the simulation with the newest valid tool pose; in lock-step mode
(``lock_step: true``) every valid tool pose is one step and the outputs carry
that pose's stamp, so replaying a bag reproduces the run exactly. rcl timers
skip ticks that were missed rather than firing them back to back, so a slow
step never piles up: the node counts the overrun and the skipped ticks and
reports them on ``/diagnostics``.

Laid out by job; :class:`TissueSimNode` only wires the parts together, each of
which takes the few objects it needs (the settings, the simulation, the clock, its publishers), never the
node, and the flow reads one way: inputs -> stepping -> outputs.

* :mod:`.inputs`: the tool inputs (checks, frames, lock-step's pairing of pose and twist by stamp, jumps);
* :mod:`.stepping`: the step timer or lock-step, the phase lock, the step itself;
* :mod:`.outputs`: a step's messages, the markers, the rest mesh (on the publishers of :mod:`.publishers`);
* :mod:`.diagnostics`: ``/diagnostics``;
* :mod:`.settings`: the parameters, declared resolved and changed at run time;
* :mod:`.recording` (``record_path``), :mod:`.clock_follow` (``follow_clock``), :mod:`.stats` (counters; the
  throttled warnings are :mod:`..throttle`'s, shared with tissue_controller);
* :mod:`.process`: the console script :func:`main` and the process-wide settings (heap, memory trace);
  :mod:`.shutdown`: a signal ends the node between two steps' outputs, never inside one.
"""
from __future__ import annotations

import math
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool, Trigger

from ...core.config import SIM_NAMES, Config
from ...core.contact.tool import ToolPose
from ...core.sim.simulation import Simulation
from ...core.timing.phase_lock import PhaseLock
from ..marker_publisher import MarkerPublisher
from ..planner_service import PlannerService
from ..tf_input import FrameInput
from ..throttle import ThrottledWarnings
from .clock_follow import ClockFollower
from .diagnostics import Diagnostics
from .inputs import ToolInputs
from .outputs import Outputs, marker_error
from .process import HeapTrimmer, MemoryTrace, main
from .publishers import NodePublishers
from .recording import NodeRecorder, start_recording
from .settings import CurrentConfig, ParameterChanges, declare_parameters
from .shutdown import OutputGate
from .stats import NodeStats
from .stepping import Stepper

__all__ = ["HeapTrimmer", "MemoryTrace", "TissueSimNode", "main"]


def start_pose(settings: Any) -> ToolPose | None:
    """The tool's start pose of the node's settings (``tool_start_*``), None without one."""
    if math.isnan(settings.tool_start_x):
        return None
    return ToolPose(settings.tool_start_x, settings.tool_start_y, settings.tool_start_yaw)


class TissueSimNode(Node):
    """The simulation as a ROS 2 node.

    Parameters
    ----------
    node_name : str
        Default ``tissue_sim_node`` (the section name in ``config/tissue_sim.yaml``).
    **kwargs
        Passed to :class:`rclpy.node.Node` (namespace, context, parameter_overrides, ...).

    Raises
    ------
    InputError
        A parameter has a bad value or the scene cannot be built; the message names it.
    """

    def __init__(self, node_name: str = "tissue_sim_node", **kwargs: Any) -> None:
        # what was given is declared as given, read, resolved and declared again (settings.declare_parameters)
        kwargs["automatically_declare_parameters_from_overrides"] = True
        super().__init__(node_name, **kwargs)
        self.recorder: NodeRecorder | None = None
        try:
            self._build()
        except BaseException:
            # a bad parameter, or SIGINT/SIGTERM while starting: end the threads already started (marker,
            # planner) and close the bag, or the interpreter's exit aborts on them ("terminate called ...")
            self.destroy_node()
            raise

    def _build(self) -> None:
        self.current = CurrentConfig(declare_parameters(self))
        settings = self.config.node
        self.sim: Simulation = Simulation.from_config(self.config)
        self.sim.warm_up()  # so JIT loading is not the first step's overrun
        self.output_gate = OutputGate()
        self.stats = NodeStats()
        self.warnings = ThrottledWarnings(self.get_logger(), self.stats.dropped, lambda: self.config.node.warn_period)
        self.topics = self._make_publishers(settings)
        self.marker_worker = MarkerPublisher(self.topics.markers.publish, nice=settings.marker_nice,
                                             on_error=marker_error(self.warnings, self.context))
        clock = self.get_clock()
        lock_step = settings.lock_step
        # timer mode's ticks move to just after the poses' arrivals; its period is the step timer's (rclpy's ns)
        phase_lock = None if lock_step else PhaseLock(int(float(self.sim.params.dt) * 1e9))
        self.outputs = Outputs(self.current, self.sim, clock, self.topics, self.marker_worker, self.warnings,
                               lock_step)
        self.frames = FrameInput(self, settings, on_bad=self.warnings.drop,
                                 on_tool_transform=lambda *a: self.inputs.on_tool_transform(*a))
        self.stepping = Stepper(self.current, self.sim, clock, self.stats, self.warnings, self.output_gate,
                                self.outputs, tool=lambda *a: self.inputs.tool_for_step(*a),
                                take_inputs=lambda: self.inputs.take_queued(), phase_lock=phase_lock,
                                logger=self.get_logger())
        self.inputs = ToolInputs(self.current, self.sim, clock, self.stats, self.warnings, self.frames, phase_lock,
                                 step=self.stepping.step, subscribe=self.create_subscription,
                                 record=self.recorder.write if self.recorder else None, start=start_pose(settings))
        if self.recorder is not None:
            self.recorder.add_subscriptions([*self.inputs.subscriptions, *self.frames.subs])
            self.frames.record = self.recorder.write
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.planner = PlannerService(self)
        self._make_timers(settings, phase_lock)
        self.parameter_changes = ParameterChanges(self.current, self.has_parameter, self._check_settings,
                                                  self._apply_settings)
        self.add_pre_set_parameters_callback(self.parameter_changes.pre_set)
        self.add_on_set_parameters_callback(self.parameter_changes.on_set)
        self.outputs.publish_rest_mesh()
        self._log_start(settings)

    def _make_publishers(self, settings: Any) -> NodePublishers:
        """Every output publisher; with ``record_path`` each also writes what it publishes into the bag."""
        publishers = NodePublishers.create(self.create_publisher)
        if settings.record_path:
            self.recorder = start_recording(settings.record_path, settings.record_storage, self.config)
            publishers = publishers.wrapped(self.recorder.wrap)
            self.get_logger().info(f"recording every message in and out to {settings.record_path} "
                                   f"({settings.record_storage})")
        return publishers

    def _make_timers(self, settings: Any, phase_lock: PhaseLock | None) -> None:
        """The step timer (timer mode), the markers' flush (lock-step), /diagnostics and the /clock follower."""
        lock_step = settings.lock_step
        self.step_timer = None if lock_step else self.create_timer(self.sim.params.dt, self.stepping.on_tick)
        if self.step_timer is not None:
            self.stepping.use_timer(self.step_timer)
        self.marker_timer = (self.create_timer(1.0 / settings.marker_rate, self.outputs.flush_markers)
                             if lock_step else None)
        self.diagnostics = Diagnostics(f"{self.get_fully_qualified_name()}: simulation", self.current, self.sim,
                                       self.get_clock(), self.stats, self.marker_worker,
                                       self.topics.markers.gil_free, phase_lock, self.topics.diagnostics,
                                       HeapTrimmer(), MemoryTrace.from_env(self.get_logger()))
        self.diagnostics_timer = self.create_timer(1.0 / settings.diagnostics_rate, self.diagnostics.publish)
        self.clock_follower = None
        if not lock_step and settings.follow_clock and not self.get_parameter("use_sim_time").value:
            topic = self.resolve_topic_name("/clock")
            self.clock_follower = ClockFollower(lambda: self.count_publishers(topic), self._use_sim_time,
                                                self._on_clock_switch, self.create_timer)

    def _log_start(self, settings: Any) -> None:
        m, p = self.sim.model, self.sim.params
        self.get_logger().info(
            f"{m.n_particles} particles, {m.n_triangles} triangles, {m.n_bodies} bodies; method {p.method}/"
            f"{p.scheme}, {p.iterations} iterations, contact {p.contact_model}; "
            f"{'lock-step' if settings.lock_step else f'{1.0 / p.dt:g} Hz'} in frame '{settings.frame_id}'; "
            f"{self.frames.status}")

    @property
    def config(self) -> Config:
        """The node's configuration as it is now (a run-time set replaces it as a whole)."""
        return self.current.value

    @property
    def frame_id(self) -> str:
        return self.config.node.frame_id

    @property
    def paused(self) -> bool:
        return bool(self.config.node.paused)

    @property
    def last_report(self) -> Any:
        """The last step's report (None before the first step)."""
        return self.stats.last_report

    # ------------------------------------------------------------------ parameters at run time

    def _check_settings(self, cfg: Config, changed: list[str]) -> None:
        """InputError unless the node can take ``cfg`` (its plane frame, its simulation's new tuning)."""
        if "frame_id" in changed:
            self.frames.check_plane(cfg.node.frame_id)
        if any(name in SIM_NAMES for name in changed):
            self.sim.retune(cfg)

    def _apply_settings(self, old: Any, new: Any) -> None:
        """Rebuild what depends on the node settings that changed from ``old`` to ``new`` (NodeConfig)."""
        if new.tf_tolerance != old.tf_tolerance:
            self.frames.buffer.tolerance_ns = int(new.tf_tolerance * 1e9)
        if (new.strain_color_max, new.wire_width, new.markers_wireframe) != \
                (old.strain_color_max, old.wire_width, old.markers_wireframe):
            self.outputs.encoder = self.outputs.make_encoder()
        if new.frame_id != old.frame_id:
            self.frames.set_plane(self, new.frame_id)  # poses in the old frame are no longer the plane's
            self.outputs.publish_rest_mesh()
        if self.marker_timer is not None and new.marker_rate != old.marker_rate:
            self.destroy_timer(self.marker_timer)
            self.marker_timer = self.create_timer(1.0 / new.marker_rate, self.outputs.flush_markers)
        if new.diagnostics_rate != old.diagnostics_rate:
            self.destroy_timer(self.diagnostics_timer)
            self.diagnostics_timer = self.create_timer(1.0 / new.diagnostics_rate, self.diagnostics.publish)
        if new.paused != old.paused:
            self.get_logger().info("paused" if new.paused else "running")

    # ------------------------------------------------------------------ services and clock

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.sim.reset()
        self.inputs.reset()
        self.stepping.reset()
        self.outputs.publish_state_now()
        response.success = True
        response.message = f"reset to the rest mesh ({self.sim.model.n_particles} particles), t = 0"
        self.get_logger().info(response.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        result = self.set_parameters([Parameter("paused", Parameter.Type.BOOL, bool(request.data))])[0]
        response.success = result.successful
        response.message = ("paused" if request.data else "running") if result.successful else result.reason
        return response

    def _use_sim_time(self, on: bool | None = None) -> bool:
        """The node's ``use_sim_time``; set to ``on`` when given."""
        if on is not None:
            self.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, on)])
        return bool(self.get_parameter("use_sim_time").value)

    def _on_clock_switch(self, following: bool) -> None:
        """The node's clock changed between /clock and the system clock: forget the input stamps."""
        self.inputs.forget_stamps()
        self.stepping.forget_schedule()
        self.get_logger().info(
            "a /clock is published: following it (use_sim_time on) while it lasts (follow_clock: false keeps the "
            "system clock)" if following else "no /clock publisher any more: back to the system clock")

    def destroy_node(self) -> None:
        """Stop the marker and planner threads, close the bag, destroy the node (also of one half built)."""
        for name in ("marker_worker", "planner", "recorder"):  # the markers before the bag: their last go in
            part = getattr(self, name, None)
            if part is not None:
                part.close()
        super().destroy_node()
