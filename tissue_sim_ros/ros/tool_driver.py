"""ToolDriver: plays a scripted tool trajectory on ``tool/pose`` and ``tool/twist``.

So a newcomer sees the simulation work without a robot::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml &
    tool_driver                                        # the paper's experiment a
    tool_driver --ros-args -p preset:=straight -p angle:=-30.0 -p target_x:=0.55 -p target_y:=0.38
    tool_driver --ros-args -p trajectory:=authors          # or a .csv/.yaml trajectory file

The trajectory is ``trajectory`` when set: a preset name or a trajectory file
(:func:`tissue_sim_ros.core.timing.trajectories.resolve_trajectory`: CSV of
time,x,y,yaw or YAML); else a named preset (``preset``, default the paper's
experiment a; :data:`tissue_sim_ros.core.timing.trajectories.PRESETS`)
or, with ``preset:=straight``, a straight insertion
(:class:`~tissue_sim_ros.core.contact.tool.StraightInsertion`) toward ``target_x,
target_y`` at ``angle`` [deg] over ``distance`` [m]. Messages go out at 1/dt
of the node's clock, stamped with that clock. Step k's message is the pose at
the end of step k and the pose change over it divided by dt, exactly the
commands :meth:`Trajectory.steps` gives an offline rollout. In ``lock_step``
mode the driver sends the next pose only once the simulation has published the
energy of the previous step, stamps poses k*dt after the start, resends a pose
that got no step within ``lock_step_timeout`` (same stamp), and paces itself
at 1/dt (``lock_step_realtime``) or as fast as the simulation steps.
"""
from __future__ import annotations

import math
import sys
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped, TwistStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..core.config import BY_NAME, Config, ParamSpec, coerce, resolve_config
from ..core.contact.tool import StraightInsertion, Trajectory
from ..core.errors import InputError
from ..core.sim.scene import tool_from_mapping
from ..core.timing.stamps import ns_from_seconds, stamp_from_ns
from ..core.timing.trajectories import preset, resolve_trajectory
from . import messages, qos
from .usage import init_rclpy, msg_docs_dir, parameter_list, usage_head, wants_help

#: The driver's own parameters, name -> (default, description); the simulation's it shares are :data:`SIM_PARAMETERS`.
DRIVER_PARAMETERS: dict[str, tuple[Any, str]] = {
    "scene": ("paper", "Shipped scene (tissue_sim_ros.core.timing.trajectories.SCENE_EXPERIMENTS: paper, liver_probe) whose experiments the presets play; its parameter file (config/scenes/NAME.yaml) gives the defaults of dt, frame_id and the tool."),
    "trajectory": ("", "A trajectory preset (experiment_a, experiment_b_shallow, experiment_b_steep, authors) or a trajectory file (.csv of time,x,y,yaw; .yaml waypoints or a straight motion); set, it replaces preset."),
    "preset": ("experiment_a", "A trajectory preset (tissue_sim_ros.core.timing.trajectories.PRESETS: experiment_a, experiment_b_shallow, experiment_b_steep, authors, retract), or 'straight' for the straight insertion the parameters below describe."),
    "target_x": (0.5, "Tip position at the end of the insertion, x [m]."),
    "target_y": (0.5, "Tip position at the end of the insertion, y [m]."),
    "angle": (0.0, "Insertion direction (the tool's yaw) [deg]; 0 = moving toward +x."),
    "distance": (0.3, "Distance the tip travels [m]."),
    "speed": (0.1, "Tip speed [m/s]."),
    "hold": (0.5, "Time held at the target after arriving [s]."),
    "wait_for_subscriber": (True, "Wait until a subscriber of tool/pose matches before starting."),
    "min_subscribers": (1, "Start once this many tool/pose subscribers match (e.g. 2: the node and a recorder)."),
    "wait_timeout": (30.0, "Give up waiting for a subscriber after this long [s]; 0 = forever."),
    "exit_when_done": (True, "Exit when the trajectory ends (else keep publishing the last pose)."),
    "lock_step": (False, "Send the next pose only after the simulation published tissue/energy for the previous one."),
    "lock_step_timeout": (1.0, "Lock-step: resend the same pose (same stamp) after this long without a step [s]: a best-effort message may be lost, and the node drops a pose it already stepped on as out of order."),
    "lock_step_realtime": (True, "Lock-step: send at most one pose per dt (real-time pace, e.g. for recording); false: as fast as the node steps."),
    "publish_twist": (True, "Also publish tool/twist (false: the node derives velocity from poses)."),
}

#: The simulation's parameters the driver shares with the node: name, type, unit and description are the one
#: table's (:data:`tissue_sim_ros.core.config.PARAMETERS`), the default is the scene's resolved value (its
#: parameter file: config/tissue_sim.yaml for ``paper``, config/scenes/NAME.yaml), so the driver publishes
#: at the simulation's dt, in its frame, with its tool.
SIM_PARAMETERS = ("dt", "frame_id", "tool_shape", "tool_length", "tool_width", "tool_radius")


def _sim_descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The descriptor of a shared parameter: the table's description and unit; read-only, as all the driver's."""
    unit = f" [{spec.unit}]" if spec.unit else ""
    return ParameterDescriptor(description=f"{spec.description}{unit} Default: the scene's parameter file.",
                               read_only=True, dynamic_typing=True)


def _scene_config(scene: str) -> Config:
    """The simulation's configuration of a shipped scene, as the node resolves it from the scene's file."""
    if scene == "paper":
        return resolve_config()
    from ..core.resources import scene_params_file  # noqa: PLC0415

    return resolve_config(params_file=scene_params_file(scene))


def default_values(scene: str = "paper") -> dict[str, Any]:
    """Every parameter's default for a shipped ``scene``: the driver's own and the scene's simulation values."""
    sim = _scene_config(scene).flat()
    return {**{name: default for name, (default, _) in DRIVER_PARAMETERS.items()},
            **{name: sim[name] for name in SIM_PARAMETERS}, "scene": scene}


def _trajectory(values: dict[str, Any]) -> Trajectory:
    """The trajectory the parameters describe (an experiment preset or a straight insertion)."""
    tool = tool_from_mapping({k: values[k] for k in ("tool_shape", "tool_length", "tool_width", "tool_radius")})
    if values.get("trajectory"):
        try:
            return resolve_trajectory(values["trajectory"], tool, values["dt"], values["scene"])
        except InputError as exc:
            raise InputError(f"parameter trajectory: {exc}") from None
    if values["preset"] != "straight":
        try:
            return preset(values["preset"], tool, values["dt"], scene=values["scene"])
        except InputError as exc:
            raise InputError(f"parameter preset: {exc}; or 'straight'") from None
    return StraightInsertion.from_angle(tool, (values["target_x"], values["target_y"]), math.radians(values["angle"]),
                                        values["distance"], values["speed"], hold=values["hold"])


class ToolDriver(Node):
    """Publishes a trajectory's poses and twists; ``done`` completes when it has played."""

    def __init__(self, node_name: str = "tool_driver", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.values: dict[str, Any] = {}
        for name, (default, description) in DRIVER_PARAMETERS.items():
            value = self.declare_parameter(name, default, ParameterDescriptor(description=description, read_only=True,
                                                                              dynamic_typing=True)).value
            if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if type(value) is not type(default):
                raise InputError(f"parameter {name}={value!r}: expected a {type(default).__name__}")
            if isinstance(value, float) and not math.isfinite(value):
                raise InputError(f"parameter {name}={value!r}: expected a finite number")
            self.values[name] = value
        # the simulation's own: declared from the one table, defaulting to the scene's resolved values
        sim = _scene_config(self.values["scene"]).flat()
        for name in SIM_PARAMETERS:
            spec = BY_NAME[name]
            value = coerce(spec, self.declare_parameter(name, sim[name], _sim_descriptor(spec)).value)
            if isinstance(value, float) and not math.isfinite(value):
                raise InputError(f"parameter {name}={value!r}: expected a finite number")
            self.values[name] = value
        if self.values["dt"] <= 0:
            raise InputError(f"parameter dt={self.values['dt']!r}: expected a period > 0 s")
        self.trajectory = _trajectory(self.values)
        self.dt: float = self.values["dt"]
        # exactly the (pose, twist) sequence an offline rollout steps through (Trajectory.steps): the pose at the
        # end of step k and the pose change over it, so a live lock-step run equals the offline one
        self.commands = list(self.trajectory.steps(self.dt))
        # the jaw angle at the end of each step (a trajectory with a jaw: published on tool/jaw before the pose)
        self.jaws = [j for *_, j in self.trajectory.steps_with_jaw(self.dt)]
        self.n_steps = len(self.commands)
        if self.n_steps == 0:
            raise InputError(f"the trajectory lasts {self.trajectory.duration} s: shorter than one step of dt={self.dt} s")
        self.k = 1
        self._acked = True
        self.done = Future()
        self.steps_seen = 0
        self._sent_at: Time | None = None
        self._start_ns: int | None = None
        self.pub_pose = self.create_publisher(PoseStamped, "tool/pose", qos.tool_output())
        self.pub_twist = self.create_publisher(TwistStamped, "tool/twist", qos.tool_output())
        self.pub_jaw = (self.create_publisher(JointState, "tool/jaw", qos.tool_output())
                        if any(j is not None for j in self.jaws) else None)
        if self.values["lock_step"]:
            self.create_subscription(Float64, "tissue/energy", self._on_energy, qos.energy())
        self._wait_start = self.get_clock().now()
        # lock-step at real-time pace checks often whether the step is acknowledged and a period has passed
        paced = self.values["lock_step"] and self.values["lock_step_realtime"]
        self.timer = self.create_timer(self.dt / 5 if paced else self.dt, self._on_tick)
        self.get_logger().info(f"{type(self.trajectory).__name__}: {self.n_steps} steps of {self.dt} s "
                               f"({'lock-step' if self.values['lock_step'] else 'timed'})")

    def _on_energy(self, msg: Float64) -> None:
        self.steps_seen += 1
        if self.values["lock_step"] and self._start_ns is not None:
            self._acked = True
            # real-time pace: send now if a period has passed since the last pose (else the next tick does),
            # so an acknowledgement arriving just after a tick does not cost a whole period
            if not self.values["lock_step_realtime"] or self._sent_at is None or \
                    (self.get_clock().now() - self._sent_at).nanoseconds >= 0.999e9 * self.dt:
                self._publish_next()

    def _ready(self) -> bool:
        """True once a subscriber matches (or waiting is off or timed out)."""
        if not self.values["wait_for_subscriber"] or \
                self.pub_pose.get_subscription_count() >= max(1, self.values["min_subscribers"]):
            return True
        waited = (self.get_clock().now() - self._wait_start).nanoseconds * 1e-9
        timeout = self.values["wait_timeout"]
        if timeout > 0 and waited > timeout:
            self.get_logger().error(f"no subscriber on {self.pub_pose.topic_name} after {timeout} s")
            self.done.set_result(False)
        return False

    def _on_tick(self) -> None:
        if self.done.done():
            return
        if self._start_ns is None:
            if not self._ready():
                return
            self._start_ns = self.get_clock().now().nanoseconds
            self._publish_next()
            return
        if self.values["lock_step"]:
            if self._acked:
                if self.values["lock_step_realtime"] and (self._sent_at is None or (
                        self.get_clock().now() - self._sent_at).nanoseconds >= 0.999e9 * self.dt):
                    self._publish_next()
                return
            if self._sent_at is not None and (self.get_clock().now() - self._sent_at).nanoseconds * 1e-9 \
                    > self.values["lock_step_timeout"]:
                # the pose (best effort) was lost: send it again, same stamp; a node that did step on it
                # drops the copy as out of order, so no step is ever taken twice
                self.get_logger().warning(f"no step for {self.values['lock_step_timeout']} s; resending step {self.k - 1}")
                self.k -= 1
                self._publish_next()
            return
        self._publish_next()

    def _publish_next(self) -> None:
        if self.done.done():
            return
        if self.k > self.n_steps:
            if self.values["exit_when_done"]:
                self.get_logger().info(f"trajectory done after {self.n_steps} steps")
                self.done.set_result(True)
                return
            self.k = self.n_steps  # keep holding the last pose
        pose, twist = self.commands[min(self.k, self.n_steps) - 1]
        now = self.get_clock().now()
        stamp_ns = self._start_ns + ns_from_seconds(self.k * self.dt) if self.values["lock_step"] else now.nanoseconds
        stamp = stamp_from_ns(stamp_ns)
        frame = self.values["frame_id"]
        if self.values["publish_twist"]:
            self.pub_twist.publish(messages.encode_twist_stamped(stamp, frame, twist.vx, twist.vy, twist.wz))
        jaw = self.jaws[min(self.k, self.n_steps) - 1]
        if self.pub_jaw is not None and jaw is not None:
            self.pub_jaw.publish(messages.encode_joint_state(stamp, "", ["jaw"], [jaw]))
        self.pub_pose.publish(messages.encode_pose_stamped(stamp, frame, pose.x, pose.y, pose.yaw))
        self._sent_at = now
        self._acked = False
        self.k += 1


def usage() -> str:
    """What ``tool_driver --help`` prints."""
    names = [*DRIVER_PARAMETERS, *SIM_PARAMETERS]
    about = (
        "Plays a scripted tool trajectory on tool/pose and tool/twist for tissue_sim_node, so the simulation can\n"
        "be seen working without a robot: by default the paper's experiment a (preset experiment_a), else a\n"
        "preset, a trajectory file (-p trajectory:=FILE.csv) or a straight insertion (-p preset:=straight).\n"
        "Exit 0 when the trajectory has played, 1 if no subscriber came, 2 on a bad parameter (named).\n\n")
    return (
        usage_head("tool_driver", about, "-p preset:=straight -p angle:=-30.0")
        + "\nparameters (all read-only):\n" + parameter_list(names) + "\n\n"
        f"Its topics and every parameter: {msg_docs_dir()}/tool_driver.md\n")


def main(args: list[str] | None = None) -> int:
    """Console script ``tool_driver``: 0 when the trajectory played, 1 if no subscriber came, 2 on a bad parameter.

    ``-h``/``--help`` outside ``--ros-args`` prints :func:`usage` and returns 0 before rclpy is initialised.
    """
    if wants_help(args):
        print(usage(), end="")
        return 0
    if not init_rclpy("tool_driver", args):
        return 2
    node = None
    code = 0
    try:
        node = ToolDriver()
        if node.values["exit_when_done"]:
            rclpy.spin_until_future_complete(node, node.done)
            code = 0 if node.done.done() and node.done.result() else 1
        else:
            rclpy.spin(node)
    except InputError as exc:
        print(f"tool_driver: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
