"""Tracked tissue points: a recording's observations, their binding to the mesh, and simulated tracks.

A recording (a camera tracking points on the tissue, the robot's tool poses)
holds any number of points at their own stamps, not at mesh vertices. Each
point is bound to the mesh by barycentric coordinates in the triangle that
holds it at the first frame (the simulation's rest configuration), so the
simulated point is ``sum_k w_k x_{tri_k}`` at every step, and simulated points
are brought to the observation stamps by linear interpolation in time between
the two steps around each stamp.

:class:`TrackSimulator` is the small interface the fit is written against:
given parameter values, the simulated tracked-point trajectories at the
observation stamps. :class:`SerialTrackSimulator` rolls the candidates out one
after another on this process; a batch pool plugs in behind the same
``simulate`` call.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from ..contact.tool import ToolPose, interpolate_poses
from ..errors import InputError
from ..mesh import TissueMesh, segment_distances

#: Fewest observation frames a fit accepts (the first one only binds the points).
MIN_FRAMES = 3


@dataclass
class Recording:
    """Observations and the tool trajectory of one recorded run, plain arrays in the simulation frame."""

    t_ns: np.ndarray
    """Observation stamps [ns], shape (F,), int64, strictly increasing."""
    points: np.ndarray
    """Tracked point positions [m], shape (F, P, 2), float64; NaN where a point was not seen in a frame."""
    tool_t_ns: np.ndarray
    """Tool pose stamps [ns], shape (M,), int64, strictly increasing."""
    tool_pose: np.ndarray
    """Tool pose x [m], y [m], yaw [rad] per stamp, shape (M, 3), float64."""
    source: str = ""
    """Where it came from (bag path and topics), for messages and the summary."""

    @property
    def n_frames(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[1])

    @property
    def duration(self) -> float:
        """First to last observation [s]."""
        return float(self.t_ns[-1] - self.t_ns[0]) * 1e-9 if self.n_frames else 0.0

    def validate(self, dt: float) -> None:
        """Raise :class:`InputError` naming what makes the recording unusable for a fit with step ``dt``."""
        src = f"recording {self.source}: " if self.source else "recording: "
        t = np.asarray(self.t_ns)
        if self.points.ndim != 3 or self.points.shape[2] != 2 or self.points.shape[0] != t.shape[0]:
            raise InputError(f"{src}points have shape {self.points.shape}: expected ({t.shape[0]}, P, 2)")
        if self.n_points == 0:
            raise InputError(f"{src}the clouds hold no points: expected at least one tracked point")
        if t.shape[0] > 1 and (np.diff(t) <= 0).any():
            k = int(np.argmax(np.diff(t) <= 0))
            raise InputError(f"{src}observation stamps out of order: frame {k + 1} at {int(t[k + 1])} ns is not after "
                             f"frame {k} at {int(t[k])} ns; expected strictly increasing stamps")
        if self.tool_t_ns.shape[0] > 1 and (np.diff(self.tool_t_ns) <= 0).any():
            k = int(np.argmax(np.diff(self.tool_t_ns) <= 0))
            raise InputError(f"{src}tool stamps out of order at sample {k + 1}: expected strictly increasing stamps")
        if self.tool_t_ns.shape[0] == 0:
            raise InputError(f"{src}no tool poses: expected the tool trajectory of the run")
        bad = ~np.isfinite(self.points[0]).all(axis=1)
        if bad.any():
            raise InputError(f"{src}point {int(np.argmax(bad))} is not finite in the first frame: every point must be "
                             "seen in the first frame, which binds it to the mesh")
        if t.shape[0] < MIN_FRAMES:
            raise InputError(f"{src}{t.shape[0]} observation frame(s): too short, expected at least {MIN_FRAMES}")
        if self.duration < 2 * dt:
            raise InputError(f"{src}spans {self.duration:.4f} s: too short, expected at least two steps of "
                             f"dt={dt} s")


@dataclass(frozen=True)
class PointBinding:
    """Each tracked point as a barycentric combination of one triangle's particles."""

    tri: np.ndarray
    """Triangle of each point, shape (P,), int64 (indices into the model's triangles)."""
    particles: np.ndarray
    """The triangle's particle indices, shape (P, 3), int64."""
    weights: np.ndarray
    """Barycentric weights, shape (P, 3), float64, rows summing to 1 (a weight < 0: just outside the triangle)."""
    outside: np.ndarray
    """Distance of the point outside the tissue at binding [m], shape (P,), 0 for points inside."""

    @property
    def n_points(self) -> int:
        return int(self.tri.shape[0])

    def positions(self, q: np.ndarray) -> np.ndarray:
        """Tracked point positions [m] for particle positions ``q`` (N, 2): shape (P, 2)."""
        return np.einsum("pk,pkd->pd", self.weights, q[self.particles])


def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric weights of points p (P, 2) in triangles (a, b, c) (T, 2): shape (P, T, 3)."""
    v0 = b - a
    v1 = c - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    det = np.where(np.abs(det) > 0, det, np.inf)  # a degenerate triangle holds nothing
    d = p[:, None, :] - a[None, :, :]
    wb = (d[..., 0] * v1[None, :, 1] - d[..., 1] * v1[None, :, 0]) / det[None, :]
    wc = (v0[None, :, 0] * d[..., 1] - v0[None, :, 1] * d[..., 0]) / det[None, :]
    return np.stack([1.0 - wb - wc, wb, wc], axis=-1)


def bind_points(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray, *, tolerance: float = 0.0,
                chunk: int = 64) -> PointBinding:
    """Bind points to the triangles holding them in the configuration ``vertices``.

    Parameters
    ----------
    vertices : particle positions at binding [m], shape (N, 2) (the rest configuration).
    triangles : particle indices, shape (T, 3).
    points : the tracked points at the first frame [m], shape (P, 2).
    tolerance : a point up to this far outside the tissue [m] is bound to the nearest triangle (weights
        extrapolated, so it follows that triangle); farther out is an :class:`InputError` naming the point.
        A coarser mesh than the one the points were tracked on cuts corners off the tissue's outline, so a
        tolerance of about a quarter of the spacing keeps points near the edge.
    """
    q = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise InputError(f"points have shape {p.shape}: expected (P, 2)")
    if not np.isfinite(p).all():
        raise InputError("points to bind must be finite")
    a, b, c = q[tris[:, 0]], q[tris[:, 1]], q[tris[:, 2]]
    n = p.shape[0]
    tri = np.empty(n, np.int64)
    weights = np.empty((n, 3))
    outside = np.zeros(n)
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        w = barycentric(p[sl], a, b, c)                         # (p, T, 3)
        worst = w.min(axis=2)                                      # > -eps: inside
        best = worst.argmax(axis=1)
        rows = np.arange(best.shape[0])
        inside = worst[rows, best] >= -1e-12
        tri[sl] = best
        weights[sl] = w[rows, best]
        if not inside.all():
            idx = np.flatnonzero(~inside)
            dist = np.minimum(np.minimum(segment_distances(p[sl][idx], a, b), segment_distances(p[sl][idx], b, c)),
                              segment_distances(p[sl][idx], c, a))  # (k, T)
            near = dist.argmin(axis=1)
            dmin = dist[np.arange(idx.size), near]
            for j, (i, t, dd) in enumerate(zip(idx, near, dmin)):
                gi = start + int(i)
                if dd > tolerance:
                    raise InputError(f"tracked point {gi} at ({p[gi, 0]:.4f}, {p[gi, 1]:.4f}) m is outside the tissue at "
                                     f"the first frame ({dd * 1e3:.2f} mm from the mesh, tolerance "
                                     f"{tolerance * 1e3:.2f} mm): expected every point on the tissue")
                tri[gi] = t
                weights[gi] = w[i, t]
                outside[gi] = dd
    return PointBinding(tri=tri, particles=tris[tri], weights=weights, outside=outside)


def binding_from_correspondence(table: np.ndarray, triangles: np.ndarray, n_vertices: int) -> PointBinding:
    """A binding given per point: rows ``(vertex,)`` (the point is that vertex) or ``(triangle, w0, w1, w2)``."""
    table = np.atleast_2d(np.asarray(table, dtype=np.float64))
    tris = np.asarray(triangles, dtype=np.int64)
    if table.shape[1] == 1:
        v = table[:, 0]
        if not (np.isfinite(v).all() and (v == np.round(v)).all() and (v >= 0).all() and (v < n_vertices).all()):
            raise InputError(f"correspondence: expected vertex indices in [0, {n_vertices}), one per point")
        v = v.astype(np.int64)
        # the triangle of each vertex, with weight 1 on the vertex
        tri_of = np.full(n_vertices, -1, np.int64)
        corner = np.zeros(n_vertices, np.int64)
        for k in range(3):
            tri_of[tris[:, k]] = np.arange(tris.shape[0])
            corner[tris[:, k]] = k
        if (tri_of[v] < 0).any():
            raise InputError(f"correspondence: vertex {int(v[np.argmax(tri_of[v] < 0)])} belongs to no triangle")
        w = np.zeros((v.size, 3))
        w[np.arange(v.size), corner[v]] = 1.0
        t = tri_of[v]
    elif table.shape[1] == 4:
        t = table[:, 0]
        if not ((t == np.round(t)).all() and (t >= 0).all() and (t < tris.shape[0]).all()):
            raise InputError(f"correspondence: expected triangle indices in [0, {tris.shape[0]})")
        t = t.astype(np.int64)
        w = table[:, 1:]
        if not np.isfinite(w).all() or (np.abs(w.sum(axis=1) - 1.0) > 1e-6).any():
            raise InputError("correspondence: barycentric weights w0, w1, w2 must be finite and sum to 1 per point")
    else:
        raise InputError(f"correspondence has {table.shape[1]} columns: expected 1 (vertex) or 4 (triangle, w0, w1, w2)")
    return PointBinding(tri=t, particles=tris[t], weights=w, outside=np.zeros(t.size))


@dataclass
class Schedule:
    """The steps a rollout takes along a recording: the sim starts at rest at the first observation."""

    t0_ns: int
    """Time of the rest state (the first observation) [ns]."""
    dt: float
    """Time step [s]."""
    tool_pose: np.ndarray
    """Tool pose at the start (row 0) and the end of every step (rows 1..K), shape (K+1, 3)."""
    frame_step: np.ndarray
    """For each observation frame, the step k with t_k <= t_frame < t_{k+1}, shape (F,), int64."""
    frame_frac: np.ndarray
    """Its fraction (t_frame - t_k) / dt in [0, 1), shape (F,)."""

    @property
    def n_steps(self) -> int:
        return int(self.tool_pose.shape[0] - 1)

    def steps_for(self, n_frames: int) -> int:
        """Steps needed to cover the first ``n_frames`` frames."""
        k = int(self.frame_step[n_frames - 1])
        return min(self.n_steps, k + (1 if self.frame_frac[n_frames - 1] > 0 else 0))

    @classmethod
    def from_recording(cls, rec: Recording, dt: float) -> "Schedule":
        dt_ns = dt * 1e9
        rel = (rec.t_ns - rec.t_ns[0]).astype(np.float64) / dt_ns
        k = np.floor(rel + 1e-9).astype(np.int64)
        frac = np.clip(rel - k, 0.0, 1.0)
        frac[frac < 1e-9] = 0.0
        n_steps = int(k[-1] + (1 if frac[-1] > 0 else 0))
        t_steps = rec.t_ns[0] + np.round(np.arange(n_steps + 1) * dt_ns).astype(np.int64)
        return cls(t0_ns=int(rec.t_ns[0]), dt=dt, tool_pose=interpolate_poses(rec.tool_t_ns, rec.tool_pose, t_steps),
                   frame_step=k, frame_frac=frac)


@dataclass
class SimulatedTracks:
    """One rollout's tracked points at the observation stamps."""

    points: np.ndarray
    """Simulated point positions [m], shape (F', P, 2), for the first F' frames."""
    contact_steps: int
    """Steps in which the tool touched the tissue."""
    diverged_steps: int = 0
    """Steps whose solve diverged (the simulation restored its state)."""


class TrackSimulator(Protocol):
    """What a fit needs: parameter values in, simulated tracked points at the observation stamps out."""

    def simulate(self, candidates: Sequence[Mapping[str, float]], n_frames: int) -> list[SimulatedTracks]:
        """Roll out every candidate (parameter name -> value) from rest over the first ``n_frames`` frames."""
        ...


def rollout_tracks(sim: Any, binding: PointBinding, schedule: Schedule, n_frames: int) -> SimulatedTracks:
    """Step ``sim`` (a fresh Simulation at rest) along ``schedule``; tracked points at the first ``n_frames`` stamps."""
    n_steps = schedule.steps_for(n_frames)
    track = np.empty((n_steps + 1, binding.n_points, 2))
    track[0] = binding.positions(sim.state.particle_q)
    poses = schedule.tool_pose
    sim.place_tool(ToolPose(float(poses[0, 0]), float(poses[0, 1]), float(poses[0, 2])))
    contact = 0
    diverged = 0
    for k in range(1, n_steps + 1):
        report = sim.step(ToolPose(float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2])))
        contact += int(bool(np.any(report.in_contact)))
        diverged += int(report.diverged)
        track[k] = binding.positions(sim.state.particle_q)
    ks = schedule.frame_step[:n_frames]
    fr = schedule.frame_frac[:n_frames, None, None]
    k1 = np.minimum(ks + 1, n_steps)
    points = (1.0 - fr) * track[ks] + fr * track[k1]
    return SimulatedTracks(points=points, contact_steps=contact, diverged_steps=diverged)


@dataclass
class SerialTrackSimulator:
    """Candidates rolled out one after another in this process.

    ``make_simulation(values)`` builds a Simulation at rest from parameter
    overrides (the scene's parameter file plus the candidate's values), e.g.
    ``lambda v: build_simulation({**base, **v}, mesh=mesh)``; the binding is
    made once, on the rest mesh.
    """

    make_simulation: Callable[[Mapping[str, float]], Any]
    binding: PointBinding
    schedule: Schedule
    on_rollout: Callable[[], None] | None = None
    n_rollouts: int = field(default=0, init=False)

    def simulate(self, candidates: Sequence[Mapping[str, float]], n_frames: int) -> list[SimulatedTracks]:
        out = []
        for values in candidates:
            sim = self.make_simulation(values)
            out.append(rollout_tracks(sim, self.binding, self.schedule, n_frames))
            self.n_rollouts += 1
            if self.on_rollout is not None:
                self.on_rollout()
        return out


#: Material values a candidate may give per body, as ``NAME@BODY`` (``young_modulus@1``).
BODY_PARAMETERS = ("young_modulus", "poisson_ratio", "thickness", "density")


def split_body_name(name: str) -> tuple[str, int | None]:
    """``young_modulus@1`` -> ("young_modulus", 1); ``young_modulus`` -> ("young_modulus", None)."""
    if "@" not in name:
        return name, None
    base, _, body = name.partition("@")
    if base not in BODY_PARAMETERS or not body.isdigit():
        raise InputError(f"parameter {name!r}: a per-body value is NAME@BODY with NAME one of "
                         f"{', '.join(BODY_PARAMETERS)} and BODY a body index (0, 1, ...)")
    return base, int(body)


def with_body_values(model: Any, body_values: Mapping[int, Mapping[str, float]]) -> Any:
    """A Model whose bodies' elements and masses use their own material values (``material: neo_hookean``).

    ``body_values``: body -> {young_modulus, poisson_ratio, thickness, density} (missing ones: the scene's).
    Each body's triangles get their rest data from :func:`~tissue_sim_ros.core.physics.material.elastic_table` with
    the body's values, and its particles their masses from its density x thickness (particles belong to one
    body), exactly as the Model builds them for the whole scene.
    """
    from dataclasses import replace  # noqa: PLC0415

    from ..physics.material import elastic_table, lumped_mass  # noqa: PLC0415

    if not body_values:
        return model
    p = model.params
    if p.material != "neo_hookean":
        raise InputError(f"per-body material values need material neo_hookean (the scene's is {p.material})")
    bad = [b for b in body_values if not 0 <= b < model.n_bodies]
    if bad:
        raise InputError(f"body {bad[0]}: the scene has bodies 0..{model.n_bodies - 1}")
    q0, tris = model.particle_q0, model.tri_indices
    elastic = np.array(model.tri_elastic, dtype=np.float64, copy=True)
    mass = np.array(model.particle_mass, dtype=np.float64, copy=True)
    for b, vals in body_values.items():
        v = {k: float(vals.get(k, getattr(p, k))) for k in BODY_PARAMETERS}
        sel = np.flatnonzero(model.tri_body == b)
        elastic[sel] = elastic_table(q0, tris[sel], v["young_modulus"], v["poisson_ratio"], v["thickness"])
        lumped = lumped_mass(q0, tris[sel], v["density"], v["thickness"])
        mine = (model.particle_body == b) & (lumped > 0)
        mass[mine] = lumped[mine]
    inv = np.where(model.particle_pinned, 0.0, 1.0 / mass)
    for arr in (elastic, mass, inv):
        arr.setflags(write=False)
    return replace(model, tri_elastic=elastic, particle_mass=mass, particle_inv_mass=inv)


@dataclass
class SceneFactory:
    """Builds the scene at rest for candidate values: ``build_simulation({**values, **candidate}, mesh=mesh)``.

    A candidate's ``NAME@BODY`` values (:data:`BODY_PARAMETERS`) set that body's material
    (:func:`with_body_values`). Plain data, so it travels to worker processes.
    """

    values: dict[str, Any]
    mesh: TissueMesh

    def __call__(self, candidate: Mapping[str, float]) -> Any:
        from ..config import resolve_config  # noqa: PLC0415  (the solvers load numba; tracking stays light)
        from ..sim.simulation import Simulation  # noqa: PLC0415

        scene: dict[str, Any] = {}
        bodies: dict[int, dict[str, float]] = {}
        for name, value in candidate.items():
            base, body = split_body_name(name)
            if body is None:
                scene[base] = value
            else:
                bodies.setdefault(body, {})[base] = value
        cfg = resolve_config({**self.values, **scene}, source="the fit's candidate values")
        sim = Simulation.from_config(cfg, mesh=self.mesh, solver=_serial_solver)
        if not bodies:
            return sim
        return Simulation(with_body_values(sim.model, bodies), tool=sim.tool, solver=_serial_solver, config=cfg)


def _serial_solver(model: Any) -> Any:
    """The scene's solver on one thread: a candidate per core, the same numbers in a worker and in this process."""
    from ..physics.solvers import Solver  # noqa: PLC0415
    from ..sim.simulation import default_solver  # noqa: PLC0415

    return default_solver(model) if model.params.sleep_speed > 0 else Solver(model, parallel=False)


_WORKER: dict[str, Any] = {}


def _worker_init(factory: SceneFactory, binding: PointBinding, schedule: Schedule) -> None:
    import os  # noqa: PLC0415

    os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # one core per candidate, as in the parent's serial runs
    _WORKER.update(factory=factory, binding=binding, schedule=schedule)
    sim = factory({})  # load the compiled kernels now, not in the first candidate
    sim.step(ToolPose(float(schedule.tool_pose[0, 0]), float(schedule.tool_pose[0, 1]), float(schedule.tool_pose[0, 2])))


def _worker_simulate(candidate: Mapping[str, float], n_frames: int) -> SimulatedTracks:
    sim = _WORKER["factory"](candidate)
    return rollout_tracks(sim, _WORKER["binding"], _WORKER["schedule"], n_frames)


class PoolTrackSimulator:
    """Candidates rolled out on persistent worker processes, one candidate per worker at a time.

    The scene (mesh, parameters), the binding and the schedule are sent to each worker once; a batch of
    candidates is spread over the workers with no barrier between candidates. The numbers are those of
    :class:`SerialTrackSimulator` bit for bit (the same rollout code on the same serial solver;
    ``test/test_fit.py`` compares them). Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, factory: SceneFactory, binding: PointBinding, schedule: Schedule, workers: int,
                 on_rollout: Callable[[], None] | None = None) -> None:
        from concurrent.futures import ProcessPoolExecutor  # noqa: PLC0415
        from multiprocessing import get_context  # noqa: PLC0415

        if workers < 1:
            raise InputError(f"workers={workers}: expected at least 1")
        self.workers = int(workers)
        self.on_rollout = on_rollout
        self.n_rollouts = 0
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=get_context("spawn"),
                                         initializer=_worker_init, initargs=(factory, binding, schedule))

    def simulate(self, candidates: Sequence[Mapping[str, float]], n_frames: int) -> list[SimulatedTracks]:
        futures = [self._pool.submit(_worker_simulate, dict(c), n_frames) for c in candidates]
        out = []
        for f in futures:
            out.append(f.result())
            self.n_rollouts += 1
            if self.on_rollout is not None:
                self.on_rollout()
        return out

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> "PoolTrackSimulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def simulate_candidate(factory: SceneFactory, binding: PointBinding, schedule: Schedule,
                       candidate: Mapping[str, float], n_frames: int) -> SimulatedTracks:
    """One candidate's rollout from the scene at rest: a self-contained call for any backend."""
    return rollout_tracks(factory(candidate), binding, schedule, n_frames)


class MappedTrackSimulator:
    """Candidates rolled out as independent calls on a backend (:func:`~tissue_sim_ros.core.sim.backends.map_calls`):
    Ray tasks on a cluster (``backend="ray"``), each worker warmed once, one core per candidate. The numbers are
    those of :class:`SerialTrackSimulator` bit for bit (the same rollout on the same serial solver;
    ``test/test_ray_backend.py`` compares them). Same interface as :class:`PoolTrackSimulator`.
    """

    def __init__(self, factory: SceneFactory, binding: PointBinding, schedule: Schedule, workers: int,
                 backend: str = "ray", address: str | None = None,
                 on_rollout: Callable[[], None] | None = None) -> None:
        if workers < 1:
            raise InputError(f"workers={workers}: expected at least 1")
        self.factory, self.binding, self.schedule = factory, binding, schedule
        self.workers, self.backend, self.address = int(workers), backend, address
        self.on_rollout = on_rollout
        self.n_rollouts = 0

    def _tick(self) -> None:
        self.n_rollouts += 1
        if self.on_rollout is not None:
            self.on_rollout()

    def simulate(self, candidates: Sequence[Mapping[str, float]], n_frames: int) -> list[SimulatedTracks]:
        from ..sim.backends import map_calls  # noqa: PLC0415  (loads the solvers; tracking stays light)

        calls = [(self.factory, self.binding, self.schedule, dict(c), n_frames) for c in candidates]
        return map_calls(simulate_candidate, calls, backend=self.backend, workers=self.workers,
                         address=self.address, progress=self._tick)

    def close(self) -> None:
        pass

    def __enter__(self) -> "MappedTrackSimulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def rms_mm(sim: np.ndarray, obs: np.ndarray) -> float:
    """RMS of the 2D distance between simulated and observed points [mm], over the finite observations."""
    d2 = ((sim - obs) ** 2).sum(axis=-1)
    ok = np.isfinite(d2)
    return float(math.sqrt(d2[ok].mean()) * 1e3) if ok.any() else float("nan")
