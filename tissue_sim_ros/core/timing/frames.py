"""Frames: the simulation plane in 3D, 3D tool poses projected onto it, and a small transform buffer.

The tissue lives in the z = 0 plane of its own frame (the node's ``frame_id``).
A robot publishes its tool in frames of its own (``base_link``, ``world``,
``tool0``...), often only as transforms on /tf. This module (no ROS; the
rotations are SciPy's :class:`~scipy.spatial.transform.Rotation`, their
interpolation its slerp) gives

* :class:`Transform`: a rigid transform (translation, unit quaternion x, y, z, w)
  with composition, inverse, and the ROS conventions: ``T_a_b`` maps points
  given in frame ``b`` into frame ``a`` (the transform of ``b`` in ``a``, what a
  ``TransformStamped`` with ``header.frame_id = a`` and ``child_frame_id = b``
  holds);
* :func:`project_pose` / :func:`project_twist`: a pose or twist in some frame
  taken into the plane frame; the tool's position is its point's x, y there
  (its height above the plane is returned, not used), its yaw the heading of
  the tool's local +x axis about the plane's normal (``atan2(R[1,0], R[0,0])``,
  the same number :func:`~tissue_sim_ros.core.contact.tool.yaw_from_quaternion` gives);
* :class:`TransformBuffer`: static and time-stamped transforms between named
  frames (a tree, as tf2's), composed along the chain from one frame to
  another, each time-varying link interpolated in time (linear in
  translation, slerp in rotation) between its two samples around the wanted
  time.

Static transforms in the static_transform_publisher order ``x y z yaw pitch
roll parent child`` parse with :func:`parse_static_transforms`.
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from functools import cached_property
from typing import Iterable

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError

Quaternion = tuple[float, float, float, float]
Vector = tuple[float, float, float]


def _quat(r: Rotation) -> Quaternion:
    return tuple(float(c) for c in r.as_quat())  # type: ignore[return-value]


def _vector(v: np.ndarray) -> Vector:
    return float(v[0]), float(v[1]), float(v[2])


def quat_normalize(q: Quaternion) -> Quaternion:
    """``q`` divided by its norm; InputError when it is no rotation (zero or not finite). Every /tf transform is
    checked so; its SciPy Rotation is made only when a lookup uses it."""
    n = math.sqrt(sum(c * c for c in q))
    if not math.isfinite(n) or n < 1e-9:
        raise InputError(f"quaternion {q}: expected a rotation (non-zero, finite)")
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> Quaternion:
    """Rotation R = Rz(yaw) Ry(pitch) Rx(roll) as (x, y, z, w) (the tf2/URDF convention: SciPy's intrinsic ZYX)."""
    return _quat(Rotation.from_euler("ZYX", [yaw, pitch, roll]))


@dataclass(frozen=True)
class Transform:
    """Rigid transform: p_parent = R(rotation) p_child + translation (the rotation a SciPy Rotation, made once)."""

    translation: Vector = (0.0, 0.0, 0.0)
    rotation: Quaternion = (0.0, 0.0, 0.0, 1.0)

    @cached_property
    def rotation_object(self) -> Rotation:
        """:attr:`rotation` as a SciPy Rotation."""
        return Rotation.from_quat(self.rotation)

    @classmethod
    def of(cls, translation: Iterable[float], rotation: Rotation) -> Transform:
        """A transform of a translation and a SciPy Rotation."""
        out = cls(_vector(np.asarray(translation, dtype=float)), _quat(rotation))
        out.__dict__["rotation_object"] = rotation  # the cached_property's own slot: no second conversion
        return out

    @classmethod
    def from_xyz_rpy(cls, x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> Transform:
        return cls((float(x), float(y), float(z)), quat_from_rpy(roll, pitch, yaw))

    @classmethod
    def checked(cls, translation: Iterable[float], rotation: Iterable[float]) -> Transform:
        """A transform from message fields: finite translation, a rotation normalised (InputError otherwise)."""
        t = tuple(float(v) for v in translation)
        if len(t) != 3 or not all(math.isfinite(v) for v in t):
            raise InputError(f"translation {t}: expected 3 finite numbers [m]")
        q = tuple(float(v) for v in rotation)
        if len(q) != 4:
            raise InputError(f"rotation {q}: expected a quaternion x, y, z, w")
        return cls(t, quat_normalize(q))  # type: ignore[arg-type]

    def __mul__(self, other: Transform) -> Transform:
        """Composition: (self * other)(p) = self(other(p)); T_a_b * T_b_c = T_a_c."""
        return Transform.of(self.apply(other.translation), self.rotation_object * other.rotation_object)

    def inverse(self) -> Transform:
        inv = self.rotation_object.inv()
        return Transform.of(-inv.apply(self.translation), inv)

    def apply(self, p: Vector) -> Vector:
        return _vector(self.rotation_object.apply(p) + self.translation)

    def rotate(self, v: Vector) -> Vector:
        """A vector (a velocity) in the child frame, in the parent's: the rotation alone."""
        return _vector(self.rotation_object.apply(v))

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_object.as_matrix()
        m[:3, 3] = self.translation
        return m

    def is_identity(self) -> bool:
        return self.translation == (0.0, 0.0, 0.0) and self.rotation == (0.0, 0.0, 0.0, 1.0)


def interpolate(a: Transform, b: Transform, s: float) -> Transform:
    """The transform a fraction s in [0, 1] of the way from a to b: linear in translation, the rotation's slerp
    the short way round (:class:`~scipy.spatial.transform.Slerp`'s formula, a times the fraction s of the
    rotation from a to b, without making a Slerp per lookup)."""
    t = tuple(x + s * (y - x) for x, y in zip(a.translation, b.translation))
    ra = a.rotation_object
    step = Rotation.from_rotvec(s * (ra.inv() * b.rotation_object).as_rotvec())
    return Transform.of(t, ra * step)


def project_pose(t_plane_src: Transform, position: Vector,
                 orientation: Quaternion) -> tuple[float, float, float, Quaternion]:
    """A pose given in a source frame, in the plane frame: (x, y, height above the plane, orientation there).

    The caller takes the yaw about the plane's normal from the returned
    orientation with :func:`~tissue_sim_ros.core.contact.tool.yaw_from_quaternion`
    (the heading of the tool's +x axis in the plane).
    """
    if t_plane_src.is_identity():  # the pose as given, to the bit (a replay of it computes the same yaw)
        return float(position[0]), float(position[1]), float(position[2]), orientation
    p = t_plane_src.apply(position)
    q = _quat(t_plane_src.rotation_object * Rotation.from_quat(orientation))
    return p[0], p[1], p[2], q


def project_twist(t_plane_src: Transform, linear: Vector, angular: Vector) -> tuple[float, float, float]:
    """A twist's linear and angular velocity given in a source frame, rotated into the plane frame: (vx, vy, wz).

    Only the rotation applies (the frames are taken as fixed to each other while
    the twist holds: no transport terms).
    """
    v, w = t_plane_src.rotate(linear), t_plane_src.rotate(angular)
    return v[0], v[1], w[2]


def parse_static_transforms(text: str) -> list[tuple[str, str, Transform]]:
    """``"x y z yaw pitch roll parent child; ..."`` (static_transform_publisher's order, metres and radians).

    Empty text: none. InputError names the entry that does not parse.
    """
    out = []
    for i, entry in enumerate(e.strip() for e in text.split(";")):
        if not entry:
            continue
        words = entry.split()
        if len(words) != 8:
            raise InputError(f"static transform {i + 1} {entry!r}: expected 'x y z yaw pitch roll parent child' "
                             "(8 words)")
        try:
            x, y, z, yaw, pitch, roll = (float(w) for w in words[:6])
        except ValueError:
            raise InputError(f"static transform {i + 1} {entry!r}: x y z yaw pitch roll must be numbers") from None
        if not all(math.isfinite(v) for v in (x, y, z, yaw, pitch, roll)):
            raise InputError(f"static transform {i + 1} {entry!r}: expected finite numbers")
        parent, child = words[6], words[7]
        if parent == child:
            raise InputError(f"static transform {i + 1} {entry!r}: parent and child are the same frame")
        out.append((parent, child, Transform.from_xyz_rpy(x, y, z, roll, pitch, yaw)))
    return out


class FrameLookupError(InputError):
    """No transform between two frames at the wanted time (unknown frame, not connected, or out of its time span)."""


class TransformBuffer:
    """Static and stamped transforms between frames: a tree, composed along chains, interpolated in time.

    Parameters
    ----------
    cache_time : float
        Seconds of history kept per time-varying link (older samples are dropped).
    tolerance : float
        A lookup up to this many seconds after a link's newest sample (or before
        its oldest) uses that sample instead of failing; beyond it the lookup
        fails (no extrapolation).
    """

    def __init__(self, cache_time: float = 10.0, tolerance: float = 0.05) -> None:
        self.cache_ns = int(cache_time * 1e9)
        self.tolerance_ns = int(tolerance * 1e9)
        self._parent: dict[str, str] = {}
        self._static: dict[str, Transform] = {}
        self._times: dict[str, list[int]] = {}
        self._samples: dict[str, deque[Transform]] = {}

    @property
    def frames(self) -> set[str]:
        return set(self._parent) | set(self._parent.values())

    def _set_parent(self, parent: str, child: str) -> None:
        if not parent or not child or parent == child:
            raise InputError(f"transform {parent!r} -> {child!r}: expected two different, non-empty frame names")
        self._parent[child] = parent  # a child has one parent (tf2's tree); a new parent replaces the old

    def set_static(self, parent: str, child: str, transform: Transform) -> None:
        """T_parent_child, valid at all times."""
        self._set_parent(parent, child)
        self._static[child] = transform
        self._times.pop(child, None)
        self._samples.pop(child, None)

    def remove(self, child: str) -> None:
        """Forget the link from ``child`` to its parent (static or stamped); nothing if there is none."""
        self._parent.pop(child, None)
        self._static.pop(child, None)
        self._times.pop(child, None)
        self._samples.pop(child, None)

    def set(self, parent: str, child: str, transform: Transform, t_ns: int) -> None:
        """T_parent_child at time t_ns; a sample older than the link's newest is inserted in order."""
        self._set_parent(parent, child)
        self._static.pop(child, None)
        times = self._times.setdefault(child, [])
        samples = self._samples.setdefault(child, deque())
        if not times or t_ns > times[-1]:
            times.append(t_ns)
            samples.append(transform)
        else:
            i = bisect.bisect_left(times, t_ns)
            if i < len(times) and times[i] == t_ns:
                samples[i] = transform
            else:
                times.insert(i, t_ns)
                samples.insert(i, transform)
        cutoff = times[-1] - self.cache_ns
        while len(times) > 2 and times[0] < cutoff:
            times.pop(0)
            samples.popleft()

    def _link(self, child: str, t_ns: int) -> Transform:
        """T_parent_child at t_ns (0: the newest)."""
        static = self._static.get(child)
        if static is not None:
            return static
        times, samples = self._times[child], self._samples[child]
        if t_ns == 0 or t_ns >= times[-1]:
            if t_ns != 0 and t_ns - times[-1] > self.tolerance_ns:
                raise FrameLookupError(
                    f"transform {self._parent[child]!r} -> {child!r} at {t_ns * 1e-9:.6f} s: its newest is "
                    f"{(t_ns - times[-1]) * 1e-9:.3f} s older (tolerance {self.tolerance_ns * 1e-9:g} s)")
            return samples[-1]
        if t_ns <= times[0]:
            if times[0] - t_ns > self.tolerance_ns:
                raise FrameLookupError(
                    f"transform {self._parent[child]!r} -> {child!r} at {t_ns * 1e-9:.6f} s: before its oldest "
                    f"kept sample by {(times[0] - t_ns) * 1e-9:.3f} s")
            return samples[0]
        i = bisect.bisect_right(times, t_ns)
        t0, t1 = times[i - 1], times[i]
        return interpolate(samples[i - 1], samples[i], (t_ns - t0) / (t1 - t0))

    def _chain(self, frame: str) -> list[str]:
        """frame, its parent, ... up to the root (cycle-safe)."""
        chain = [frame]
        seen = {frame}
        while chain[-1] in self._parent:
            parent = self._parent[chain[-1]]
            if parent in seen:
                raise FrameLookupError(f"frames form a loop through {parent!r}")
            chain.append(parent)
            seen.add(parent)
        return chain

    def can_transform(self, target: str, source: str, t_ns: int = 0) -> bool:
        try:
            self.lookup(target, source, t_ns)
        except FrameLookupError:
            return False
        return True

    def lookup(self, target: str, source: str, t_ns: int = 0) -> Transform:
        """T_target_source at time t_ns (0: the newest of every link): maps points in ``source`` into ``target``."""
        if target == source:
            return Transform()
        known = self.frames
        for f in (target, source):
            if f not in known:
                raise FrameLookupError(f"frame {f!r} is unknown: known frames are "
                                       f"{', '.join(sorted(known)) or 'none'}")
        up_source, up_target = self._chain(source), self._chain(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            raise FrameLookupError(f"frames {source!r} and {target!r} are not connected (roots {up_source[-1]!r} "
                                   f"and {up_target[-1]!r})")
        t_common_source = self._compose(up_source[:up_source.index(common)], t_ns)
        t_common_target = self._compose(up_target[:up_target.index(common)], t_ns)
        if t_common_target is None:
            return t_common_source or Transform()
        inverse = t_common_target.inverse()
        return inverse if t_common_source is None else inverse * t_common_source

    def _compose(self, chain: list[str], t_ns: int) -> Transform | None:
        """T_top_frame of ``chain`` (a frame, its parent, ... short of the top), None for an empty chain."""
        out = None
        for f in chain:
            link = self._link(f, t_ns)
            out = link if out is None else link * out
        return out
