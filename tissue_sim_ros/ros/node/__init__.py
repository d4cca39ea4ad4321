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
which takes the node as an argument:

* :mod:`.inputs`: the tool inputs (checks, frames, lock-step's pairing of pose and twist by stamp, jumps);
* :mod:`.stepping`: the step timer or lock-step, the phase lock, the step itself;
* :mod:`.outputs`: a step's messages, the markers, the rest mesh, ``/diagnostics``;
* :mod:`.settings`: the parameters, declared resolved and changed at run time;
* :mod:`.recording` (``record_path``), :mod:`.clock_follow` (``follow_clock``), :mod:`.stats` (counters; the
  throttled warnings are :mod:`..throttle`'s, shared with tissue_controller);
* :mod:`.process`: the console script :func:`main` and the process-wide settings (heap, memory trace);
  :mod:`.shutdown`: a signal ends the node between two steps' outputs, never inside one.
"""
from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import Float64, Float64MultiArray, UInt32
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ...core.config import Config
from ...core.sim.simulation import Simulation, StepReport
from .. import messages, qos
from ..marker_publisher import MarkerPublisher
from ..planner_service import PlannerService
from ..raw_publish import GilFreePublisher
from ..tf_input import FrameInput
from ..throttle import ThrottledWarnings
from .clock_follow import ClockFollower
from .inputs import ToolInputs
from .outputs import Outputs
from .process import HeapTrimmer, MemoryTrace, main
from .recording import NodeRecorder, start_recording
from .settings import ParameterChanges, declare_parameters
from .shutdown import OutputGate
from .stats import NodeStats
from .stepping import Stepper

__all__ = ["HeapTrimmer", "MemoryTrace", "TissueSimNode", "main"]


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
        super().__init__(node_name, **kwargs)
        try:
            self._build()
        except BaseException:
            # a bad parameter, or SIGINT/SIGTERM while starting: end the threads already started (marker,
            # planner) and close the bag, or the interpreter's exit aborts on them ("terminate called ...")
            self.destroy_node()
            raise

    def _build(self) -> None:
        # the settings and the simulation they describe
        self.config: Config = declare_parameters(self)
        settings = self.config.node
        self.sim: Simulation = Simulation.from_config(self.config)
        self.sim.warm_up()  # so JIT loading is not the first step's overrun
        self.last_report: StepReport | None = None

        # the parts, by job
        self.output_gate = OutputGate()
        self.stats = NodeStats()
        self.warnings = ThrottledWarnings(self.get_logger(), self.stats.dropped,
                                          lambda: self.config.node.warn_period)
        self.inputs = ToolInputs(self)
        self.stepping = Stepper(self)
        self.outputs = Outputs(self)
        self.parameter_changes = ParameterChanges(self)

        # outputs; 1 MB of markers at 5k triangles: published without holding the GIL, so the step thread
        # runs meanwhile (raw_publish.py)
        self.pub_markers = GilFreePublisher(
            self.create_publisher(MarkerArray, "tissue/markers", qos.state_stream(qos.MARKER_DEPTH)))
        self.pub_points = self.create_publisher(PointCloud2, "tissue/points", qos.state_stream())
        self.pub_rest = self.create_publisher(MarkerArray, "tissue/rest_mesh", qos.latched())
        self.pub_wrench = self.create_publisher(WrenchStamped, "tool/wrench", qos.state_stream())
        self.pub_energy = self.create_publisher(Float64, "tissue/energy", qos.energy())
        self.pub_energy_terms = {term: self.create_publisher(Float64, f"tissue/energy/{term}", qos.energy())
                                 for term in messages.ENERGY_TERMS[:3]}
        self.pub_energy_bodies = self.create_publisher(Float64MultiArray, "tissue/energy/bodies", qos.energy())
        self.pub_contact = self.create_publisher(Float64MultiArray, "tissue/contact", qos.energy())
        # material: dt^2 E_strain (a term of the total) and the potential energy itself in J (msg_docs/topics.md)
        self.pub_energy_terms.update({term: self.create_publisher(Float64, f"tissue/energy/{term}", qos.energy())
                                      for term in ("strain", "potential", "attach")})
        # a grasper's: the particles held (each step; tool_shape grasper only) (msg_docs/topics.md)
        self.pub_grasped = self.create_publisher(UInt32, "tool/grasped", qos.energy())
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", qos.diagnostics())
        self.pub_applied_pose = self.create_publisher(PoseStamped, "tool/applied_pose", qos.state_stream())
        self.pub_applied_twist = self.create_publisher(TwistStamped, "tool/applied_twist", qos.state_stream())
        self.pub_applied_jaw = self.create_publisher(JointState, "tool/applied_jaw", qos.state_stream())

        # inputs; the pose with its message info: its reception time is the pose's arrival for the phase lock
        lock_step = settings.lock_step
        self.frames = FrameInput(self, settings, on_tool_transform=self.inputs.on_tool_transform,
                                 on_bad=self.warnings.drop)
        self.sub_pose = self.create_subscription(PoseStamped, "tool/pose",
                                                 lambda msg, info: self.inputs.on_pose(msg, info),
                                                 qos.tool_input(lock_step))
        self.sub_twist = self.create_subscription(TwistStamped, "tool/twist", self.inputs.on_twist,
                                                  qos.tool_input(lock_step))
        self.sub_jaw = self.create_subscription(JointState, "tool/jaw", self.inputs.on_jaw, qos.tool_input(lock_step))
        self.recorder: NodeRecorder | None = None
        if settings.record_path:
            self.recorder = start_recording(self, settings.record_path, settings.record_storage)

        # threads: markers encoded and published on their own (the step thread never waits for 1 MB of DDS),
        # the planner's service ~/plan_insertion
        self.marker_worker = MarkerPublisher(lambda data: self.pub_markers.publish(data),
                                             on_error=self.outputs.marker_error, nice=settings.marker_nice)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.planner = PlannerService(self)

        # timers
        self.step_timer = None if lock_step else self.create_timer(self.sim.params.dt, self.stepping.on_tick)
        self.marker_timer = (self.create_timer(1.0 / settings.marker_rate, self.outputs.flush_markers)
                             if lock_step else None)
        if self.step_timer is not None:
            self.stepping.use_timer(self.step_timer)
        self.clock_follower = (ClockFollower(self, self._on_clock_switch)
                               if not lock_step and settings.follow_clock
                               and not self.get_parameter("use_sim_time").value else None)
        self.diagnostics_timer = self.create_timer(1.0 / settings.diagnostics_rate, self.outputs.publish_diagnostics)
        self.heap_trimmer = HeapTrimmer()
        self.memory_trace = MemoryTrace.from_env(self.get_logger())

        # parameter changes at run time
        self.add_pre_set_parameters_callback(self.parameter_changes.pre_set)
        self.add_on_set_parameters_callback(self.parameter_changes.on_set)

        self.outputs.publish_rest_mesh()
        m = self.sim.model
        self.get_logger().info(
            f"{m.n_particles} particles, {m.n_triangles} triangles, {m.n_bodies} bodies; method "
            f"{self.sim.params.method}/{self.sim.params.scheme}, {self.sim.params.iterations} iterations, contact "
            f"{self.sim.params.contact_model}; {'lock-step' if lock_step else f'{1.0 / self.sim.params.dt:g} Hz'} "
            f"in frame '{settings.frame_id}'; {self.frames.status}")

    @property
    def frame_id(self) -> str:
        return self.config.node.frame_id

    @property
    def paused(self) -> bool:
        return bool(self.config.node.paused)

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

