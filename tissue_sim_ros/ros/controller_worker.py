"""``tissue_controller``'s worker: the thread that owns the controller and its state.

The executor's callbacks only hand the worker the newest observation (:meth:`ControllerWorker.put_points`,
``put_pose``, ``put_jaw``) and the ``~/move_tissue`` requests (:meth:`ControllerWorker.request`); the worker makes
every call into the controller (the requests' ``set_goal`` and ``planned_path``, each step's ``command``) in the
order they come, so nothing planning does blocks a subscription and a run is as deterministic as the
observations it was given. What it is doing (:class:`Pursuit`) is its own, written under its lock; the
diagnostics read a copy (:meth:`ControllerWorker.snapshot`). A replan longer than dt makes it skip to the newest
points (``skipped_points``); the simulator meanwhile holds the last pose.
"""
from __future__ import annotations

import copy
import math
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..core.contact.tool import ToolPose
from ..core.errors import InputError

STATES = ("idle", "pursuing", "reached", "gave up", "refused")


@dataclass
class Observation:
    """The newest points: stamp [ns], frame, positions (N, 2) [m]."""

    stamp_ns: int
    frame: str
    xy: np.ndarray


@dataclass
class MoveRequest:
    """A ``~/move_tissue`` request handed to the worker, and its answer."""

    start: tuple[float, float]
    goal: tuple[float, float]
    obs: Observation
    pose: ToolPose
    jaw: float
    done: threading.Event
    path: np.ndarray | None = None
    reason: str = ""


@dataclass
class Pursuit:
    """What the worker is doing and has done (the controller's /diagnostics, msg_docs/controller.md)."""

    state: str = "idle"
    reason: str = ""
    last_refusal: str = ""
    phase: str = "none"
    goal_error: float = math.nan
    observed_error: float = math.nan
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    goal_particle: int = -1
    goal_point: int = -1
    """The observed point nearest the start at the request (its index in the cloud)."""
    t_start_ns: int = 0
    elapsed: float = 0.0
    held_since_ns: int | None = None
    hold_cmd: tuple[ToolPose, float] | None = None
    last_replan_ms: float = math.nan
    max_replan_ms: float = math.nan
    last_sync_ms: float = math.nan
    latency: tuple[float, int, float] = (0.0, 0, 0.0)
    """Of the commands for the current goal: (sum, count, max) of the points' stamp to publication [ms]."""
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("points_received", "poses_received", "jaws_received", "requests", "accepted", "refused", "commands",
         "skipped_points", "replans", "unpublished_nonfinite"), 0))
    grasp_site: Any = None

    def refuse(self, reason: str) -> None:
        """A refused request: counted and named; it leaves a goal pursued or held alone."""
        self.counts["refused"] += 1
        self.last_refusal = reason
        if self.state not in ("pursuing", "reached"):
            self.state, self.reason = "refused", reason

    def observed_error_of(self, obs: Observation) -> float:
        """The distance from the goal of the observed point that was nearest the start at the request [m]."""
        i = self.goal_point
        if self.goal is None or i < 0 or i >= obs.xy.shape[0] or not np.isfinite(obs.xy[i]).all():
            return math.nan
        return float(np.hypot(*(obs.xy[i] - self.goal)))


class ControllerWorker:
    """The worker thread (module docstring).

    Parameters
    ----------
    ctrl : TissueController
        Made and warmed up by the node; only this thread calls it from now on.
    settings : ControlSettings
        Its settings (the goal's tolerance, the open jaw).
    dt_ns : int
        The model's step [ns].
    output : CommandOutput
        Publishes the commands and the plan's markers.
    now_ns : callable
        The node clock's time [ns].
    logger
        The node's logger.
    max_time, hold_time : float
        Give a goal up after pursuing it this long [s]; it is reached once held within tolerance this long [s].
    start : callable, optional
        Run first on the worker thread (lowering its priority); returns its niceness or None.
    """

    def __init__(self, ctrl: Any, settings: Any, dt_ns: int, output: Any, now_ns: Callable[[], int], logger: Any,
                 max_time: float, hold_time: float, start: Callable[[], int | None] | None = None) -> None:
        self.ctrl, self.settings, self.dt_ns, self.output = ctrl, settings, dt_ns, output
        self.now_ns, self.logger, self.max_time, self.hold_time = now_ns, logger, max_time, hold_time
        self._start = start
        self.niceness: int | None = None
        self.pursuit = Pursuit()
        self._cond = threading.Condition()
        self.obs: Observation | None = None
        self._obs_taken = True
        self.n_points: int | None = None
        self.plane_frame: str | None = None
        self.pose: ToolPose | None = None
        self._pose_ns = -1
        self.jaw: float | None = None
        self._request: MoveRequest | None = None
        self._stopping = False
        self._thread = threading.Thread(target=self._work, name="controller", daemon=True)

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # ------------------------------------------------------------------ the executor's side

    def check_points(self, n: int, frame: str) -> tuple[str, str]:
        """('', '') when a cloud of ``n`` points in ``frame`` can be used, else (drop kind, why not)."""
        with self._cond:
            if self.n_points is not None and n != self.n_points:
                return "points_shape", f"has {n} points: expected {self.n_points}, as the first cloud"
            if self.plane_frame is not None and frame != self.plane_frame:
                return "points_frame", f"in frame '{frame}': expected '{self.plane_frame}', the first cloud's"
        return "", ""

    def put_points(self, obs: Observation) -> None:
        with self._cond:
            self.n_points, self.plane_frame = obs.xy.shape[0], obs.frame
            if not self._obs_taken and self.pursuit.state == "pursuing":
                self.pursuit.counts["skipped_points"] += 1
            self.obs, self._obs_taken = obs, False
            self.pursuit.counts["points_received"] += 1
            self._cond.notify_all()

    def put_pose(self, pose: ToolPose, stamp_ns: int, frame: str) -> str:
        """'' when taken, else why not (another frame than the points')."""
        with self._cond:
            if self.plane_frame is not None and frame != self.plane_frame:
                return f"in frame '{frame}': expected '{self.plane_frame}', the points' frame"
            self.pose, self._pose_ns = pose, stamp_ns
            self.pursuit.counts["poses_received"] += 1
            self._cond.notify_all()
        return ""

    def put_jaw(self, jaw: float) -> None:
        with self._cond:
            self.jaw = jaw
            self.pursuit.counts["jaws_received"] += 1

    def inputs(self) -> tuple[Observation | None, ToolPose | None, float | None, str | None]:
        """The newest points, pose, jaw and the plane's frame, for a request; the request counted."""
        with self._cond:
            self.pursuit.counts["requests"] += 1
            return self.obs, self.pose, self.jaw, self.plane_frame

    def refuse(self, reason: str) -> None:
        with self._cond:
            self.pursuit.refuse(reason)

    def request(self, req: MoveRequest, shutting_down: Callable[[], bool]) -> None:
        """Hand ``req`` to the worker and wait for its answer (or for the node to stop)."""
        with self._cond:
            self._request = req
            self._cond.notify_all()
        while not req.done.wait(0.1):
            if shutting_down() or not self.alive:
                req.reason = "the node is shutting down"
                return

    def snapshot(self) -> Pursuit:
        """A copy of the pursuit, for /diagnostics."""
        with self._cond:
            return copy.deepcopy(self.pursuit)

    def close(self) -> None:
        """Stop the worker (after its current call) and the controller's rollout pool."""
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)
        if self.ctrl.pool is not None:
            self.ctrl.pool.close()
            self.ctrl.pool = None

    # ------------------------------------------------------------------ the worker's side

    def _work(self) -> None:
        if self._start is not None:
            self.niceness = self._start()
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001  a controller bug must not leave the node looking alive
            reason = f"the controller failed: {type(exc).__name__}: {exc}"
            self.logger.error(f"the controller's worker stopped: {type(exc).__name__}: {exc}")
            with self._cond:
                self.pursuit.state, self.pursuit.reason = "gave up", reason
                req = self._request
            if req is not None:
                req.reason = reason
                req.done.set()

    def _next(self, last_ns: int) -> tuple[MoveRequest | None, Observation | None] | None:
        """The next request, or points to step on (None: stop)."""
        p = self.pursuit
        with self._cond:
            self._cond.wait_for(lambda: self._stopping or self._request is not None or (
                p.state in ("pursuing", "reached") and self.obs is not None and self.obs.stamp_ns != last_ns),
                timeout=0.1)
            if self._stopping:
                return None
            req, self._request = self._request, None
            obs = None
            if req is None and p.state in ("pursuing", "reached") and self.obs is not None \
                    and self.obs.stamp_ns != last_ns:
                obs, self._obs_taken = self.obs, True
            return req, obs

    def _loop(self) -> None:
        last_ns = -1
        while True:
            taken = self._next(last_ns)
            if taken is None:
                return
            req, obs = taken
            if req is not None:
                self._serve(req)
                continue
            p = self.pursuit
            if p.state == "pursuing":
                p.elapsed = (self.now_ns() - p.t_start_ns) * 1e-9
                if p.elapsed > self.max_time:
                    self._give_up(f"the goal was not reached within max_time={self.max_time:g} s "
                                  f"(goal error {p.goal_error * 1e3:.2f} mm, phase {p.phase})")
                    continue
            if obs is None:
                continue
            last_ns = obs.stamp_ns
            with self._cond:  # the measured pose of the points' step (published just after them), briefly waited for
                self._cond.wait_for(lambda: self._stopping or self._pose_ns >= obs.stamp_ns,
                                    timeout=0.5 * self.dt_ns * 1e-9)
                pose, jaw = self.pose, self.jaw
            if p.state == "reached":
                self._publish(obs, *p.hold_cmd, 0.0, 0.0, 0.0)
            elif p.state == "pursuing":
                self._step(obs, pose, self.settings.open_jaw if jaw is None else jaw)

    def _serve(self, req: MoveRequest) -> None:
        """set_goal and planned_path on the request's observation; the answer in ``req``."""
        ctrl = self.ctrl
        try:
            ids = ctrl.set_goal([(req.start, req.goal)], req.obs.xy, req.pose)  # (a hold is let go: a new approach)
            path = ctrl.planned_path(req.obs.xy, req.pose, req.jaw, t=req.obs.stamp_ns * 1e-9)
            if not np.isfinite(path).all():
                raise InputError("the plan is not finite")
        except InputError as exc:
            req.reason = str(exc)
            req.done.set()
            return
        except Exception as exc:  # noqa: BLE001  a controller bug: refused, named
            self.logger.error(f"move_tissue: the controller failed: {type(exc).__name__}: {exc}")
            req.reason = f"the controller failed: {type(exc).__name__}: {exc}"
            req.done.set()
            return
        with self._cond:
            p = self.pursuit
            p.goal_particle = int(ids[0]) if len(ids) else -1
            d = np.hypot(*(req.obs.xy - np.array(req.start)).T)
            p.goal_point = int(np.argmin(np.where(np.isfinite(d), d, np.inf)))
            p.start, p.goal = ctrl.starts[0].copy(), np.array(req.goal)
            p.state, p.reason, p.phase = "pursuing", "", ctrl.phase
            p.goal_error = ctrl.goal_error(ctrl.x)
            p.observed_error = p.observed_error_of(req.obs)
            p.t_start_ns, p.elapsed, p.held_since_ns, p.hold_cmd = self.now_ns(), 0.0, None, None
            p.latency = (0.0, 0, 0.0)
            p.grasp_site = ctrl.site
            p.counts["accepted"] += 1
        req.path = path
        req.done.set()
        self.output.markers(req.obs, path, ctrl.records[-1] if ctrl.records else None, p.start, p.goal)

    def _command(self, obs: Observation, pose: ToolPose, jaw: float) -> Any:
        """The controller's command for ``obs``, or None (the goal given up, with the reason)."""
        try:
            cmd = self.ctrl.command(obs.xy, pose, jaw, t=obs.stamp_ns * 1e-9)
        except InputError as exc:
            self._give_up(f"the controller refused the observation: {exc}")
            return None
        except Exception as exc:  # noqa: BLE001
            self._give_up(f"the controller failed: {type(exc).__name__}: {exc}")
            return None
        values = (cmd.pose.x, cmd.pose.y, cmd.pose.yaw, cmd.twist.vx, cmd.twist.vy, cmd.twist.wz, cmd.jaw)
        if not all(math.isfinite(x) for x in values):
            with self._cond:
                self.pursuit.counts["unpublished_nonfinite"] += 1
            self._give_up(f"the controller's command is not finite (pose {cmd.pose}, twist {cmd.twist}, jaw "
                          f"{cmd.jaw}): not published")
            return None
        return cmd

    def _step(self, obs: Observation, pose: ToolPose, jaw: float) -> None:
        cmd = self._command(obs, pose, jaw)
        if cmd is None:
            return
        self._publish(obs, cmd.pose, cmd.jaw, cmd.twist.vx, cmd.twist.vy, cmd.twist.wz)
        if cmd.replanned and self.ctrl.records:
            self._replanned(obs, cmd)
        p, s = self.pursuit, self.settings
        with self._cond:
            p.phase, p.goal_error, p.grasp_site = cmd.phase, cmd.goal_error, self.ctrl.site
            p.observed_error = p.observed_error_of(obs)
            if cmd.phase == "holding" and cmd.goal_error <= s.tolerance:
                if p.held_since_ns is None:
                    p.held_since_ns = obs.stamp_ns
                if (obs.stamp_ns - p.held_since_ns) * 1e-9 >= self.hold_time - 1e-9:
                    p.state, p.hold_cmd = "reached", (cmd.pose, cmd.jaw)
            else:
                p.held_since_ns = None
        if p.state == "reached":
            self.logger.info(
                f"goal reached: goal error {cmd.goal_error * 1e3:.2f} mm (observed {p.observed_error * 1e3:.2f} "
                f"mm) within goal_tolerance {s.tolerance * 1e3:g} mm for {self.hold_time:g} s, after "
                f"{p.elapsed:.2f} s; holding the tool at ({cmd.pose.x:.4f}, {cmd.pose.y:.4f})")

    def _replanned(self, obs: Observation, cmd: Any) -> None:
        rec, p = self.ctrl.records[-1], self.pursuit
        with self._cond:
            p.counts["replans"] += 1
            p.last_replan_ms, p.last_sync_ms = rec.total_s * 1e3, rec.sync_s * 1e3
            p.max_replan_ms = p.last_replan_ms if math.isnan(p.max_replan_ms) else max(p.max_replan_ms,
                                                                                       p.last_replan_ms)
        self.logger.debug(
            f"replan at step {rec.step} ({rec.phase}): sync {rec.sync_s * 1e3:.1f} ms, {rec.candidates} "
            f"candidates x {rec.horizon} steps {rec.rollout_s * 1e3:.1f} ms, choice {rec.choose_s * 1e3:.1f} ms; "
            f"goal error {cmd.goal_error * 1e3:.2f} mm")
        if rec.paths:
            self.output.markers(obs, None, rec, p.start, p.goal)

    def _publish(self, obs: Observation, pose: ToolPose, jaw: float, vx: float, vy: float, wz: float) -> None:
        """The command, stamped with the points' stamp + dt (the step it is meant for); its latency counted."""
        self.output.command(obs, self.dt_ns, pose, jaw, vx, vy, wz)
        with self._cond:
            p = self.pursuit
            p.counts["commands"] += 1
            if obs.stamp_ns > 0:  # from the points' stamp to the command's publication (on the node's clock)
                lat = (self.now_ns() - obs.stamp_ns) * 1e-6
                p.latency = (p.latency[0] + lat, p.latency[1] + 1, max(p.latency[2], lat))

    def _give_up(self, reason: str) -> None:
        with self._cond:
            self.pursuit.state, self.pursuit.reason = "gave up", reason
        self.logger.error(f"gave up: {reason}")
