"""The tool: shape, planar pose and velocity, and trajectories as data.

All in the simulation frame: x right, y up, yaw about +z (the tool's heading in
the tissue plane). A tool's long axis is its local +x, except the grasper's: its pose is the point midway
between its jaw tips and at yaw 0 its shaft points up (+y) from there, jaws down (it comes from above).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

TOOL_SHAPES = ("box", "capsule", "sphere", "grasper")


@dataclass(frozen=True)
class ToolShape:
    """Tool geometry in the tool frame (local +x is the long axis, the tip at +length/2).

    * ``box``: a ``length`` x ``width`` rectangle (the paper's authors used 0.8 x 0.005);
    * ``capsule``: a segment of ``length`` along +x, inflated by ``radius``;
    * ``sphere``: a disc of ``radius``;
    * ``grasper``: a shaft of ``shaft_width`` ending in two jaws of ``jaw_length``, ``length`` long in all
      (tip to shaft end). Its pose is the point midway between the jaw tips; at yaw 0 the shaft points +y.
      Contact sees its envelope: a capsule of radius ``shaft_width / 2`` from the tip (its lowest point is the
      pose) up the shaft, open or closed; the jaws inside it are drawn (:meth:`outline`), and grasp what lies
      within ``grasp_radius`` of the tip (``core/sim/grasp.py``).
    """

    kind: str = "box"
    length: float = 0.8
    """Length along the tool axis [m] (box, capsule)."""
    width: float = 0.005
    """Full width of a box [m]."""
    radius: float = 0.0025
    """Radius of a capsule or sphere [m]."""
    jaw_length: float = 0.01
    """Grasper: length of each jaw [m] (drawn; the grasp reaches ``grasp_radius`` from the tip)."""
    shaft_width: float = 0.005
    """Grasper: full width of the shaft [m] (the contact envelope's diameter)."""

    def __post_init__(self) -> None:
        if self.kind not in TOOL_SHAPES:
            raise InputError(f"tool_shape={self.kind!r}: expected one of {', '.join(TOOL_SHAPES)}")
        for name in ("length", "width", "radius", "jaw_length", "shaft_width"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise InputError(f"tool_{name}={value!r}: expected a finite size >= 0 m")
        if self.kind == "box" and (self.length <= 0 or self.width <= 0):
            raise InputError(f"box tool needs tool_length and tool_width > 0; got {self.length}, {self.width}")
        if self.kind in ("capsule", "sphere") and self.radius <= 0:
            raise InputError(f"{self.kind} tool needs tool_radius > 0; got {self.radius}")
        if self.kind == "grasper":
            if self.shaft_width <= 0 or self.jaw_length <= 0:
                raise InputError(f"grasper tool needs shaft_width and jaw_length > 0; got {self.shaft_width}, "
                                 f"{self.jaw_length}")
            if self.length < self.shaft_width or self.length < self.jaw_length:
                raise InputError(f"grasper tool_length={self.length!r}: expected at least shaft_width "
                                 f"({self.shaft_width}) and jaw_length ({self.jaw_length}) [m]")

    def rounded_box(self) -> tuple[float, float, float]:
        """The shape as a rounded box: half extents (hx, hy) and corner radius, all [m].

        Box: (length/2, width/2, 0); capsule: (length/2, 0, radius); sphere: (0, 0, radius); grasper: its
        envelope, a capsule (length/2 - shaft_width/2, 0, shaft_width/2) along the shaft (centred
        :meth:`contact_pose`).
        """
        if self.kind == "grasper":
            r = 0.5 * self.shaft_width
            return 0.5 * self.length - r, 0.0, r
        if self.kind == "box":
            return 0.5 * self.length, 0.5 * self.width, 0.0
        if self.kind == "capsule":
            return 0.5 * self.length, 0.0, self.radius
        return 0.0, 0.0, self.radius


    def contact_pose(self, pose: "ToolPose") -> tuple[float, float, float]:
        """Centre [m] and axis angle [rad] of :meth:`rounded_box` for the tool at ``pose``: the pose itself, but
        for the grasper, whose envelope's centre is ``length / 2`` up the shaft from the tip and whose long
        axis (local +x of the rounded box) is the shaft, at yaw + pi/2."""
        if self.kind != "grasper":
            return pose.x, pose.y, pose.yaw
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        half = 0.5 * self.length
        return pose.x - s * half, pose.y + c * half, pose.yaw + 0.5 * math.pi

    def outline(self, jaw: float | None = None, segments: int = 8) -> np.ndarray:
        """Closed outline in the tool's pose frame (the frame :class:`ToolPose` places), (K, 2) float64 [m].

        The rounded box for box, capsule and sphere. The grasper: with ``jaw`` None its contact envelope
        (convex, for the markers), else its shaft and two jaws opened to ``jaw`` [rad] (the full angle between
        them; below 0: closed), for the pictures.
        """
        if self.kind != "grasper":
            return rounded_box_outline(*self.rounded_box(), segments=segments)
        if jaw is None:
            # the contact envelope (convex: the markers fan it from its centre): the capsule up the shaft
            env = rounded_box_outline(*self.rounded_box(), segments=segments)
            return np.stack([-env[:, 1], env[:, 0] + 0.5 * self.length], axis=1)
        w, lj = 0.5 * self.shaft_width, self.jaw_length
        half = 0.5 * min(max(0.0 if jaw is None else float(jaw), 0.0), math.pi / 2)
        s, c = math.sin(half), math.cos(half)
        # the jaws hinge at the shaft's end (y = jaw_length), each a thin blade turned out by half the angle
        hinge = lj
        pts = [(-w, self.length), (-w, hinge), (-s * lj - 0.3 * w * c, hinge - c * lj),
               (-s * lj + 0.3 * w * c, hinge - c * lj), (0.0, hinge - 0.4 * w),
               (s * lj - 0.3 * w * c, hinge - c * lj), (s * lj + 0.3 * w * c, hinge - c * lj), (w, hinge),
               (w, self.length)]
        return np.array(pts, dtype=np.float64)


@dataclass(frozen=True)
class ToolPose:
    """Planar pose of the tool's centre: position [m] and yaw [rad]."""

    x: float
    y: float
    yaw: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.yaw], dtype=np.float64)


@dataclass(frozen=True)
class ToolTwist:
    """Planar velocity of the tool's centre: linear [m/s] and angular [rad/s]."""

    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.vx, self.vy, self.wz], dtype=np.float64)


def rounded_box_outline(hx: float, hy: float, radius: float, segments: int = 8) -> np.ndarray:
    """Closed outline of a rounded box in the tool frame, counter-clockwise, shape (K, 2), float64 [m].

    ``hx, hy`` are the half extents of the inner box and ``radius`` the rounding
    (see :meth:`ToolShape.rounded_box`); drawn by the node's tool marker and the pictures.
    """
    if radius <= 0.0:
        return np.array([[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]], dtype=np.float64)
    out = []
    for cx, cy, a0 in ((hx, -hy, -0.5 * math.pi), (hx, hy, 0.0), (-hx, hy, 0.5 * math.pi), (-hx, -hy, math.pi)):
        a = a0 + np.linspace(0.0, 0.5 * math.pi, segments + 1)
        out.append(np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a)], axis=1))
    return np.concatenate(out)


def tool_shape_array(shape: ToolShape, pose: ToolPose, margin: float = 0.0) -> np.ndarray:
    """Pack a posed shape for numba kernels: [cx, cy, cos(yaw), sin(yaw), hx, hy, radius + margin], float64 (7,).

    (cx, cy, yaw) is :meth:`ToolShape.contact_pose`: the pose itself but for the grasper (its envelope's centre).
    """
    hx, hy, rr = shape.rounded_box()
    cx, cy, yaw = shape.contact_pose(pose)
    return np.array([cx, cy, math.cos(yaw), math.sin(yaw), hx, hy, rr + margin], dtype=np.float64)


# --------------------------------------------------------------------------- trajectories


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float | None:
    """Heading about +z [rad] of a quaternion (x, y, z, w); None when it is not a rotation (zero or non-finite).

    A slightly denormalised quaternion (common in robot bags) is normalised first. The one formula the node,
    bag replay and demo share, so an offline replay equals the node in lock-step to the bit.
    """
    n2 = x * x + y * y + z * z + w * w
    if not math.isfinite(n2) or n2 < 1e-12:
        return None
    if abs(n2 - 1.0) > 1e-9:
        s = 1.0 / math.sqrt(n2)
        x, y, z, w = x * s, y * s, z * s, w * s
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def wrap_angle(a: float) -> float:
    """An angle wrapped to [-pi, pi) [rad]; an angle already in that range is returned as it is (to the bit)."""
    if -math.pi <= a < math.pi:
        return float(a)
    return float((a + math.pi) % (2.0 * math.pi) - math.pi)


def twist_from_poses(prev: ToolPose | None, pose: ToolPose, dt: float) -> ToolTwist:
    """The tool's velocity over a step: the pose change divided by ``dt`` [s], yaw along the shortest arc.

    The one conversion the simulation (a step without a twist), trajectories
    (:meth:`Trajectory.steps`) and the benchmarks share: a yaw step from
    +179 deg to -179 deg is +2 deg, not -358 deg. No previous pose: zero.
    """
    if prev is None:
        return ToolTwist()
    return ToolTwist((pose.x - prev.x) / dt, (pose.y - prev.y) / dt, wrap_angle(pose.yaw - prev.yaw) / dt)


def interpolate_poses(t_src: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses at times ``t``, linear in x, y and unwrapped yaw between samples, clamped outside their span.

    Parameters
    ----------
    t_src : sample times, shape (M,), strictly increasing (any unit; int64 ns are made relative first).
    poses : x [m], y [m], yaw [rad] per sample, shape (M, 3).
    t : query times in the unit of ``t_src``, shape (K,).

    Returns shape (K, 3), float64, yaw wrapped to [-pi, pi].
    """
    t_src = np.asarray(t_src)
    origin = t_src[0]
    ts = (t_src - origin).astype(np.float64)
    tq = (np.asarray(t) - origin).astype(np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    out = np.empty((tq.shape[0], 3))
    out[:, 0] = np.interp(tq, ts, poses[:, 0])
    out[:, 1] = np.interp(tq, ts, poses[:, 1])
    yaw = np.interp(tq, ts, np.unwrap(poses[:, 2]))
    out[:, 2] = np.arctan2(np.sin(yaw), np.cos(yaw))
    return out


def _check_point(name: str, p: object) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in p)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InputError(f"{name}={p!r}: expected a point (x, y) in metres") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"{name}={p!r}: expected finite coordinates")
    return x, y


class Trajectory:
    """A tool trajectory as data: the pose and twist of the tool's centre at any time.

    Subclasses define :meth:`pose_at`, :meth:`twist_at`, :attr:`start_time` and
    :attr:`duration`. :meth:`steps` turns it into the per-step commands of
    :meth:`~tissue_sim_ros.core.sim.simulation.Simulation.step`.
    """

    start_time: float = 0.0

    @property
    def duration(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def pose_at(self, t: float) -> ToolPose:  # pragma: no cover - abstract
        raise NotImplementedError

    def twist_at(self, t: float) -> ToolTwist:  # pragma: no cover - abstract
        raise NotImplementedError

    def jaw_at(self, t: float) -> float | None:
        """The grasper's jaw angle at ``t`` [rad]; None: the trajectory does not drive the jaw."""
        return None

    def steps_with_jaw(self, dt: float):
        """Iterate ``(pose, twist, jaw)`` for steps k = 1..n: :meth:`steps` with the jaw angle at the end of
        step k (None when the trajectory has no jaw), as ``Simulation.step(pose, twist, jaw=jaw)`` and
        :func:`~tissue_sim_ros.core.sim.rollout.rollout` take them."""
        end = self.start_time + self.duration
        for k, (pose, twist) in enumerate(self.steps(dt), start=1):
            yield pose, twist, self.jaw_at(min(self.start_time + k * dt, end))

    def n_steps(self, dt: float) -> int:
        """Steps of ``dt`` needed to cover :attr:`duration` (the last one may be partial)."""
        if not (math.isfinite(dt) and dt > 0):
            raise InputError(f"dt={dt!r}: expected a time step > 0 s")
        # the small tolerance keeps an exact multiple (0.5 / 0.01) from rounding up to one more step
        return max(0, math.ceil(self.duration / dt - 1e-9))

    def steps(self, dt: float):
        """Iterate ``(pose, twist)`` for steps k = 1..n: the pose at the end of step k.

        The twist is the pose change over the step divided by ``dt`` (yaw along
        the shortest arc), i.e. exactly what a simulation derives from
        consecutive poses; at the end the pose is clamped to the last one.
        """
        n = self.n_steps(dt)
        end = self.start_time + self.duration
        prev = self.pose_at(self.start_time)
        for k in range(1, n + 1):
            t = min(self.start_time + k * dt, end)
            pose = self.pose_at(t)
            yield pose, twist_from_poses(prev, pose, dt)
            prev = pose


@dataclass(frozen=True)
class StraightInsertion(Trajectory):
    """Straight insertion: the tool tip moves from ``start`` to ``target`` at a constant speed, then stops.

    The tool points along the motion (yaw = the insertion angle, the direction
    start -> target), tip first; its pose is its centre, ``tip_offset`` behind
    the tip (``length / 2`` for a box or capsule, 0 for a sphere: see
    :meth:`from_tool`).

    Parameters
    ----------
    start, target : (float, float)
        Tip position at t = 0 and at the end [m].
    speed : float
        Tip speed: [m/s], or [m per step] when ``dt`` is given (the authors used 0.001 m per step).
    tip_offset : float
        Distance from the tool's centre to its tip along its axis [m].
    dt : float, optional
        Step [s] for a speed given per step.
    hold : float
        Time spent at the target after arriving [s].
    """

    start: tuple[float, float]
    target: tuple[float, float]
    speed: float
    tip_offset: float = 0.4
    dt: float | None = None
    hold: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", _check_point("start", self.start))
        object.__setattr__(self, "target", _check_point("target", self.target))
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise InputError(f"speed={self.speed!r}: expected a speed > 0")
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt={self.dt!r}: expected a time step > 0 s (or None for a speed in m/s)")
        if not (math.isfinite(self.tip_offset) and self.tip_offset >= 0):
            raise InputError(f"tip_offset={self.tip_offset!r}: expected a distance >= 0 m")
        if not (math.isfinite(self.hold) and self.hold >= 0):
            raise InputError(f"hold={self.hold!r}: expected a time >= 0 s")
        if self.length == 0.0:
            raise InputError(f"start={self.start} equals target={self.target}: expected two distinct points")

    @classmethod
    def from_tool(cls, tool: ToolShape, start: tuple[float, float], target: tuple[float, float], speed: float,
                  dt: float | None = None, hold: float = 0.0) -> "StraightInsertion":
        """An insertion of ``tool`` (its tip is ``length / 2`` ahead of its centre; a sphere's is its centre)."""
        offset = 0.0 if tool.kind in ("sphere", "grasper") else 0.5 * tool.length
        return cls(start, target, speed, tip_offset=offset, dt=dt, hold=hold)

    @classmethod
    def from_angle(cls, tool: ToolShape, target: tuple[float, float], angle: float, distance: float, speed: float,
                   dt: float | None = None, hold: float = 0.0) -> "StraightInsertion":
        """Insertion at ``angle`` [rad] (the tip's direction of motion) ending at ``target`` after ``distance`` [m]."""
        tx, ty = _check_point("target", target)
        if not (math.isfinite(angle)):
            raise InputError(f"angle={angle!r}: expected a finite angle in rad")
        if not (math.isfinite(distance) and distance > 0):
            raise InputError(f"distance={distance!r}: expected an insertion distance > 0 m")
        start = (tx - distance * math.cos(angle), ty - distance * math.sin(angle))
        return cls.from_tool(tool, start, (tx, ty), speed, dt=dt, hold=hold)

    @property
    def length(self) -> float:
        """Distance the tip travels [m]."""
        return math.hypot(self.target[0] - self.start[0], self.target[1] - self.start[1])

    @property
    def angle(self) -> float:
        """Insertion angle: the tool's yaw, the direction start -> target [rad]."""
        return math.atan2(self.target[1] - self.start[1], self.target[0] - self.start[0])

    @property
    def speed_mps(self) -> float:
        """Tip speed [m/s]."""
        return self.speed / self.dt if self.dt is not None else self.speed

    @property
    def travel_time(self) -> float:
        """Time to reach the target [s]."""
        return self.length / self.speed_mps

    @property
    def duration(self) -> float:
        return self.travel_time + self.hold

    def tip_at(self, t: float) -> tuple[float, float]:
        """Tip position at time ``t`` [s] (start before 0, target after arrival) [m]."""
        s = min(max(t, 0.0) * self.speed_mps, self.length) / self.length
        return (self.start[0] + s * (self.target[0] - self.start[0]), self.start[1] + s * (self.target[1] - self.start[1]))

    def pose_at(self, t: float) -> ToolPose:
        tx, ty = self.tip_at(t)
        yaw = self.angle
        return ToolPose(tx - self.tip_offset * math.cos(yaw), ty - self.tip_offset * math.sin(yaw), yaw)

    def twist_at(self, t: float) -> ToolTwist:
        """Velocity at ``t``: the insertion velocity while moving (0 <= t < travel time), else zero."""
        if 0.0 <= t < self.travel_time:
            v = self.speed_mps
            return ToolTwist(v * math.cos(self.angle), v * math.sin(self.angle), 0.0)
        return ToolTwist()


@dataclass(frozen=True)
class WaypointTrajectory(Trajectory):
    """Timed poses of the tool's centre, linearly interpolated (yaw along the shortest arc).

    Parameters
    ----------
    times : array of float, shape (K,)
        Strictly increasing times [s]; the trajectory starts at ``times[0]``.
    poses : sequence of ToolPose, or array shape (K, 3) of [x, y, yaw]
        Pose of the tool's centre at each time [m, m, rad].
    hold : float
        Time the last pose is held after ``times[-1]`` [s].
    jaws : array of float, shape (K,), optional
        The grasper's jaw angle at each time [rad], linearly interpolated (held before and after); None: no jaw.
    """

    times: np.ndarray
    poses: np.ndarray
    hold: float = 0.0
    jaws: np.ndarray | None = None

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        raw = self.poses
        if len(raw) and isinstance(raw[0], ToolPose):  # type: ignore[index]
            poses = np.array([p.as_array() for p in raw], dtype=np.float64)  # type: ignore[union-attr]
        else:
            poses = np.asarray(raw, dtype=np.float64)
        if times.size < 1:
            raise InputError("waypoint trajectory has no waypoints: expected at least one (time, pose)")
        if poses.shape != (times.size, 3):
            raise InputError(f"waypoint poses have shape {poses.shape}: expected ({times.size}, 3) [x, y, yaw]")
        if not (np.isfinite(times).all() and np.isfinite(poses).all()):
            raise InputError("waypoint times and poses must be finite")
        if times.size > 1 and np.any(np.diff(times) <= 0):
            k = int(np.argmax(np.diff(times) <= 0))
            raise InputError(f"waypoint times must increase strictly; times[{k}]={times[k]} >= times[{k + 1}]={times[k + 1]}")
        if not (math.isfinite(self.hold) and self.hold >= 0):
            raise InputError(f"hold={self.hold!r}: expected a time >= 0 s")
        if self.jaws is not None:
            jaws = np.asarray(self.jaws, dtype=np.float64).reshape(-1)
            if jaws.shape != times.shape or not np.isfinite(jaws).all():
                raise InputError(f"waypoint jaws have shape {jaws.shape}: expected ({times.size},) finite angles [rad]")
            jaws.setflags(write=False)
            object.__setattr__(self, "jaws", jaws)
        times.setflags(write=False)
        poses.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "poses", poses)

    @property
    def start_time(self) -> float:  # type: ignore[override]
        return float(self.times[0])

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) + self.hold

    def _segment(self, t: float) -> int:
        """Index k of the segment [times[k], times[k+1]) holding t (right-continuous at knots)."""
        return int(np.searchsorted(self.times, t, side="right")) - 1

    def pose_at(self, t: float) -> ToolPose:
        """Pose at ``t``: the first pose before ``times[0]``, the last after ``times[-1]``."""
        times, poses = self.times, self.poses
        if t <= times[0]:
            return ToolPose(*map(float, poses[0]))
        if t >= times[-1]:
            return ToolPose(*map(float, poses[-1]))
        k = self._segment(t)
        s = (t - times[k]) / (times[k + 1] - times[k])
        p0, p1 = poses[k], poses[k + 1]
        yaw = wrap_angle(p0[2] + s * wrap_angle(p1[2] - p0[2]))
        return ToolPose(float(p0[0] + s * (p1[0] - p0[0])), float(p0[1] + s * (p1[1] - p0[1])), yaw)

    def jaw_at(self, t: float) -> float | None:
        """The jaw angle at ``t`` [rad], linear between waypoints, held outside them; None without jaws."""
        if self.jaws is None:
            return None
        return float(np.interp(t, self.times, self.jaws))

    def twist_at(self, t: float) -> ToolTwist:
        """Velocity of the segment holding ``t`` (constant per segment); zero outside [times[0], times[-1])."""
        times, poses = self.times, self.poses
        if t < times[0] or t >= times[-1]:
            return ToolTwist()
        k = self._segment(t)
        return twist_from_poses(ToolPose(*map(float, poses[k])), ToolPose(*map(float, poses[k + 1])),
                                float(times[k + 1] - times[k]))
