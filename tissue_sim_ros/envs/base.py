"""What every tissue task shares: the scene, the action, the observation, randomisation, rendering.

:class:`TissueEnv` is a goal-conditioned :class:`gymnasium.Env` in the convention of gymnasium-robotics: its
observation is a Dict of ``observation`` (a flat vector), ``achieved_goal`` and ``desired_goal``, and its reward is
:meth:`TissueEnv.compute_reward` of the two goals (and ``info``), vectorised over leading batch dimensions so that
hindsight relabelling (HER) calls it on whole batches. A task (:mod:`.retract`, :mod:`.probe`, :mod:`.shape`) says
which scene it loads, what its goals are and how it rewards.

The simulation is the core's :class:`~tissue_sim_ros.core.sim.simulation.Simulation`, built once per environment
from the scene's parameter file (``config/scenes/*.yaml``) with the constructor's ``params`` over it: solver,
contact and material settings are the scene's, so whatever the scene resolves to is what the task steps. Each step
is one ``Simulation.step(pose, jaw=...)``; what the wrapper adds (the action's clip and scaling, the tracked
points, the reward and ``info``) is plain NumPy on a few dozen numbers, so it stays a small share of the step
(``tissue-sim bench envs`` measures it).

The observation vector, in this order (float32, SI units):

* ``points``: the tracked tissue points (K, 2) [m], flattened: material points embedded in the rest mesh by
  barycentric weights (:func:`~tissue_sim_ros.core.plan.observe.embed`), on a grid over the tissue, so they are
  the same material points whatever the mesh spacing; Gaussian noise of ``point_noise`` [m] when asked;
* ``tool``: the tool tip's x, y [m] and the tool's yaw [rad] (the grasper's pose is its tip, a box's tip is
  ``length / 2`` ahead of its centre);
* ``jaw`` [rad] (0 for a tool without jaws) and the number of particles the jaw holds;
* ``wrench``: the tissue's reaction on the tool, F_x, F_y [N] and the torque about the tool's centre [N m].

Randomisation (constructor arguments, and per episode ``reset(options=...)`` with the same names): each of
``young_modulus``, ``poisson_ratio``, ``damping`` and ``point_noise`` is None (the scene's), a number, or a
``(low, high)`` pair drawn uniformly per episode from the environment's seeded generator; ``goal_region`` is the
task's. The same seed gives the same episode bit for bit: the draws come from ``self.np_random`` in a fixed order,
and every episode starts from the same solver state (a snapshot of the freshly retuned scene, see
:meth:`TissueEnv._start_episode`), whatever ran before.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..core.config import Config, resolve_config
from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.plan.observe import embed
from ..core.resources import scene_params_file
from ..core.sim.simulation import Simulation, StepReport

#: material parameters a task randomises (``Config`` names), in the order they are drawn
MATERIAL = ("young_modulus", "poisson_ratio", "damping")
#: every randomisable name: the material, then the observation noise
RANDOMISED = (*MATERIAL, "point_noise")
#: the observation vector's layout after the points: tip x, tip y, yaw, jaw, held, F_x, F_y, torque
TOOL_FIELDS = ("tip_x", "tip_y", "yaw", "jaw", "held", "force_x", "force_y", "torque")


def draw(rng: np.random.Generator, name: str, spec: Any) -> float | None:
    """A value for ``name`` from ``spec``: None (the scene's), a number, or a (low, high) pair drawn uniformly."""
    if spec is None:
        return None
    if isinstance(spec, (int, float, np.floating, np.integer)) and not isinstance(spec, bool):
        return float(spec)
    lo, hi = range_of(name, spec)
    return float(rng.uniform(lo, hi))


def range_of(name: str, spec: Any) -> tuple[float, float]:
    """``spec`` as a finite (low, high) pair with low <= high; InputError naming ``name`` otherwise."""
    try:
        lo, hi = (float(v) for v in spec)
    except (TypeError, ValueError):
        raise InputError(f"{name}={spec!r}: expected a number or a (low, high) pair") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InputError(f"{name}={spec!r}: expected finite low <= high")
    return lo, hi


def check_spec(name: str, spec: Any, *, low: float = 0.0, strict: bool = True, high: float = math.inf) -> Any:
    """``spec`` checked (number or range inside (low, high) or [low, high) when not ``strict``); returned as given."""
    if spec is None:
        return None
    values = [spec] if isinstance(spec, (int, float, np.floating, np.integer)) and not isinstance(spec, bool) \
        else list(range_of(name, spec))
    for v in values:
        ok = math.isfinite(float(v)) and (float(v) > low if strict else float(v) >= low) and float(v) < high
        if not ok:
            bound = f"> {low:g}" if strict else f">= {low:g}"
            raise InputError(f"{name}={spec!r}: expected values {bound}" + (f" and < {high:g}" if high < math.inf
                                                                              else ""))
    return spec


def grid_points(q0: np.ndarray, tris: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` material points inside the rest mesh, on a grid over its bounding box: (tris (K, 3), weights (K, 3)).

    The grid's aspect follows the tissue's and is refined until it holds at least ``count`` points inside a
    triangle; ``count`` of those, evenly spread along the grid's order, are kept. Deterministic for a mesh.
    """
    lo, hi = q0.min(axis=0), q0.max(axis=0)
    span = np.maximum(hi - lo, 1e-12)
    for n in range(max(2, int(math.sqrt(count))), 200):
        nx = max(2, int(round(n * math.sqrt(span[0] / span[1]))))
        ny = max(2, int(round(n * math.sqrt(span[1] / span[0]))))
        gx = lo[0] + span[0] * (np.arange(nx) + 0.5) / nx
        gy = lo[1] + span[1] * (np.arange(ny) + 0.5) / ny
        pts = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
        t, w = embed(pts, q0, tris)
        inside = np.hypot(*((w[:, :, None] * q0[t]).sum(axis=1) - pts).T) <= 1e-9 * float(span.max())
        if inside.sum() >= count:
            keep = np.flatnonzero(inside)[np.linspace(0, inside.sum() - 1, count).round().astype(int)]
            return t[keep], w[keep]
    raise InputError(f"n_points={count}: the tissue holds fewer grid points; expected fewer points")


class TissueEnv(gym.Env):
    """A tissue task (module docstring). Subclasses set the class attributes and the goal methods.

    Parameters
    ----------
    render_mode : {None, "rgb_array", "human"}
        ``rgb_array``: :meth:`render` returns an (H, W, 3) uint8 frame (OpenCV); ``human``: a window (needs a
        display; refused with an InputError where there is none).
    reward_type : {"dense", "sparse"}
    params : mapping, optional
        Parameters over the scene's file (``Config`` names: ``{"contact_model": "projection"}``...).
    spacing : float, optional
        The mesh spacing [m] (default: the scene's): coarser steps faster (docs/envs.md measures it).
    young_modulus, poisson_ratio, damping, point_noise : number or (low, high), optional
        Randomised per episode (module docstring).
    goal_region : optional
        The task's region its goals are drawn from (see the task).
    n_points : int
        Tracked points in the observation.
    tolerance : float, optional
        Success distance [m] (default: the task's).
    width, height : int
        The rendered frame's size [px].
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 25}
    scene: str = "retract"
    """The shipped scene (``config/scenes/{scene}.yaml``), or "" for the shipped default (the paper's)."""
    scene_defaults: Mapping[str, Any] = {}
    """Parameters under the scene's file (the command-line defaults of the scene's experiment)."""
    max_speed: float = 0.05
    """The tool tip's speed at action +-1 [m/s] along each axis."""
    max_yaw_rate: float = 0.0
    """The yaw rate at action +-1 [rad/s]; 0: the action has no yaw component."""
    jaw_open: float = 0.0
    """The jaw angle at action +1 [rad]; 0: the action has no jaw component (action -1 closes it to 0)."""
    default_tolerance: float = 0.002
    goal_size: int = 2
    n_points_default: int = 16

    def __init__(self, render_mode: str | None = None, *, reward_type: str = "dense",
                 params: Mapping[str, Any] | None = None, spacing: float | None = None, young_modulus: Any = None,
                 poisson_ratio: Any = None, damping: Any = None, point_noise: Any = 0.0, goal_region: Any = None,
                 n_points: int | None = None, tolerance: float | None = None, width: int = 480,
                 height: int = 320) -> None:
        super().__init__()
        from .frame import display_available  # noqa: PLC0415  (light: OpenCV is imported by the project anyway)

        why = display_available()
        # this machine's modes: check_env (and a user listing them) tries each, and "human" needs a display
        self.metadata = {**self.metadata, "render_modes": ["rgb_array"] + ([] if why else ["human"])}
        if render_mode == "human" and why:  # refused now, not at the first render() deep inside a training loop
            raise InputError(f"render_mode='human': {why}; expected a desktop session, or render_mode='rgb_array'")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise InputError(f"render_mode={render_mode!r}: expected None or one of "
                             f"{', '.join(self.metadata['render_modes'])}")
        if reward_type not in ("dense", "sparse"):
            raise InputError(f"reward_type={reward_type!r}: expected dense or sparse")
        self.render_mode = render_mode
        self.reward_type = reward_type
        overrides = dict(params or {})
        if spacing is not None:
            overrides["spacing"] = float(check_spec("spacing", spacing))
        files = [scene_params_file(self.scene)] if self.scene else None
        self.config: Config = resolve_config(overrides, params_file=files, defaults=dict(self.scene_defaults),
                                             source="params")
        self.randomise = {"young_modulus": check_spec("young_modulus", young_modulus),
                          "poisson_ratio": check_spec("poisson_ratio", poisson_ratio, strict=False, high=0.5),
                          "damping": check_spec("damping", damping, strict=False),
                          "point_noise": check_spec("point_noise", point_noise, strict=False)}
        if not self.config.sim.material == "neo_hookean":
            for name in ("young_modulus", "poisson_ratio"):
                if self.randomise[name] is not None:
                    raise InputError(f"{name}={self.randomise[name]!r} with material "
                                     f"{self.config.sim.material!r}, which ignores it: expected params "
                                     "{'material': 'neo_hookean'} to randomise it")
        self.goal_region = self.check_goal_region(goal_region)
        self.tolerance = float(check_spec("tolerance", self.default_tolerance if tolerance is None else tolerance))
        self.width, self.height = int(width), int(height)
        if self.width < 16 or self.height < 16:
            raise InputError(f"width={width}, height={height}: expected a frame of at least 16 x 16 px")

        self.mesh = self.config.scene.build_mesh()
        self.sim = Simulation.from_config(self.config, mesh=self.mesh)
        if self.sim.tool is None:
            raise InputError("the scene has no tool: expected a tool_shape")
        # numba kernels and python-fcl load here, once per process (each vector-env worker builds its own)
        self.sim.warm_up()
        self.dt = float(self.sim.params.dt)
        model = self.sim.model
        self.q0 = np.asarray(model.particle_q0, dtype=np.float64)
        self.tris = np.asarray(model.tri_indices, dtype=np.int64)
        count = self.n_points_default if n_points is None else int(n_points)
        if count < 1:
            raise InputError(f"n_points={n_points!r}: expected an integer >= 1")
        self.point_tris, self.point_w = grid_points(self.q0, self.tris, count)
        self.point_matrix = embedding_matrix(self.point_tris, self.point_w, self.q0.shape[0])
        """(K, N): the tracked points are ``point_matrix @ x`` (one small product a step instead of a gather and an
        einsum: a sixth of the cost on the retraction flap)."""
        self.goal_matrix = np.zeros((0, self.q0.shape[0]))
        """(G, N): the achieved goal's tissue points are ``goal_matrix @ x`` (a task sets it)."""
        tool = self.sim.tool
        self.tip_offset = 0.0 if tool.kind in ("sphere", "grasper") else 0.5 * tool.length
        lo, hi = self.q0.min(axis=0), self.q0.max(axis=0)
        self.workspace = self.make_workspace(lo, hi)
        """The tip's box (x_min, y_min, x_max, y_max) [m]: actions that would leave it are clipped at it."""

        n_act = 2 + (self.max_yaw_rate > 0) + (self.jaw_open > 0)
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        n_obs = 2 * count + len(TOOL_FIELDS)
        self.observation_space = spaces.Dict({
            "observation": spaces.Box(-np.inf, np.inf, (n_obs,), dtype=np.float32),
            "achieved_goal": spaces.Box(-np.inf, np.inf, (self.goal_size,), dtype=np.float32),
            "desired_goal": spaces.Box(-np.inf, np.inf, (self.goal_size,), dtype=np.float32),
        })
        self._material_key: tuple | None = None
        self._fresh = None
        self.episode = 0
        """Episodes started (an expert keyed on it knows a new one began)."""
        self.episode_material: dict[str, float] = {}
        self.noise = 0.0
        self.tip = np.zeros(2)
        self.yaw = 0.0
        self.jaw = 0.0
        self.goal = np.zeros(self.goal_size)
        self.report: StepReport | None = None
        self.steps = 0
        self._window = None
        self._frame = None

    # ------------------------------------------------------------------------------------------ task hooks
    def make_workspace(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The tip's box from the rest mesh's bounds (x_min, y_min, x_max, y_max) [m]."""
        return np.array([lo[0] - 0.02, lo[1], hi[0] + 0.02, hi[1] + 0.03])

    def check_goal_region(self, region: Any) -> Any:
        return region

    def start_pose(self) -> tuple[np.ndarray, float, float]:
        """The episode's first tip position [m], yaw [rad] and jaw [rad] (after the goal is drawn)."""
        raise NotImplementedError

    def draw_goal(self, rng: np.random.Generator, options: Mapping[str, Any]) -> np.ndarray:
        """The episode's desired goal (``goal_size``,), from the task's region (or ``options['goal']``)."""
        raise NotImplementedError

    def achieved(self) -> np.ndarray:
        """The achieved goal now (``goal_size``,) float64: the tissue points of :attr:`goal_matrix` (a task whose goal
        is not on the tissue overrides it)."""
        return (self.goal_matrix @ self.sim.state.particle_q).reshape(-1)

    def distance(self, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
        """The goal distance [m] over the last axis (a task of several points: the largest point's)."""
        if self.goal_size == 2 and np.ndim(achieved_goal) == 1 and np.ndim(desired_goal) == 1:
            # one goal, every step: plain floats (a tenth of NumPy's cost on two numbers), and the same bits as the
            # batch below (sqrt of dx^2 + dy^2, both correctly rounded), so a relabelled reward equals the step's
            dx = float(achieved_goal[0]) - float(desired_goal[0])
            dy = float(achieved_goal[1]) - float(desired_goal[1])
            return np.float64(math.sqrt(dx * dx + dy * dy))
        d = np.asarray(achieved_goal, dtype=np.float64) - np.asarray(desired_goal, dtype=np.float64)
        if self.goal_size == 2:
            return np.sqrt((d * d).sum(axis=-1))
        d = d.reshape(*d.shape[:-1], -1, 2)
        return np.sqrt((d * d).sum(axis=-1)).max(axis=-1)

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> Any:
        """Sparse: 0 within ``tolerance`` of the goal, else -1; dense: minus the distance in cm. Vectorised over
        leading batch dimensions (HER relabels with it); returns a float for one goal, float32 arrays otherwise."""
        d = self.distance(achieved_goal, desired_goal)
        if np.ndim(d) == 0:
            return -float(d > self.tolerance) if self.reward_type == "sparse" else -float(d) / 0.01
        r = -(d > self.tolerance).astype(np.float64) if self.reward_type == "sparse" else -d / 0.01
        return r.astype(np.float32)

    def compute_terminated(self, achieved_goal: Any, desired_goal: Any, info: Any) -> Any:
        """Episodes end only at the time limit (or a diverged step, in :meth:`step`), as in gymnasium-robotics'
        Fetch tasks: a policy learns to hold the goal, and HER relabels whole episodes."""
        return False

    def compute_truncated(self, achieved_goal: Any, desired_goal: Any, info: Any) -> Any:
        return False

    # ------------------------------------------------------------------------------------------ the episode
    def _start_episode(self, material: Mapping[str, float | None]) -> None:
        """The scene at t = 0 with this episode's material, in the same solver state whatever ran before.

        A new material is :meth:`Simulation.retune` (a fresh solver, nothing carried over) and a reset, and the
        scene is then kept as a snapshot; the same material again restores that snapshot (a retune builds a
        solver, a restore copies arrays). Both start the step from the same numbers.
        """
        key = tuple(material[k] for k in MATERIAL)
        if key != self._material_key:
            changes = {k: v for k, v in material.items() if v is not None}
            cfg = self.config.replace(**changes) if changes else self.config
            self.sim.retune(cfg)
            self.sim.reset()
            self._fresh = self.sim.snapshot()
            self._material_key = key
        else:
            self.sim.restore(self._fresh)

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        known = {*RANDOMISED, "goal", "goal_region"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise InputError(f"reset option {unknown[0]!r}: expected one of {', '.join(sorted(known))}")
        rng = self.np_random
        spec = {k: check_spec(k, options[k], strict=k == "young_modulus", high=0.5 if k == "poisson_ratio"
                              else math.inf) if k in options else self.randomise[k] for k in RANDOMISED}
        material = {k: draw(rng, k, spec[k]) for k in MATERIAL}
        self.noise = draw(rng, "point_noise", spec["point_noise"]) or 0.0
        self.episode_material = {k: (v if v is not None else float(getattr(self.config.sim, k)))
                                 for k, v in material.items()}
        self._start_episode(material)
        if "goal_region" in options:
            options["goal_region"] = self.check_goal_region(options["goal_region"])
        self.goal = np.asarray(self.draw_goal(rng, options), dtype=np.float64).reshape(self.goal_size)
        tip, yaw, jaw = self.start_pose()
        self.tip, self.yaw, self.jaw = np.array(tip, dtype=np.float64), float(yaw), float(jaw)
        self.sim.place_tool(self.pose())
        self.report = None
        self.steps = 0
        self.episode += 1
        obs = self._observation()
        info = self._info(None, obs["achieved_goal"], obs["desired_goal"])
        if self.render_mode == "human":
            self.render()
        return obs, info

    def pose(self) -> ToolPose:
        """The tool's pose (its centre for a box) from the tip and yaw."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return ToolPose(float(self.tip[0] - self.tip_offset * c), float(self.tip[1] - self.tip_offset * s), self.yaw)

    def command(self, action: Any) -> tuple[np.ndarray, float, float]:
        """The next tip position, yaw and jaw from an action in [-1, 1] (clipped there, and the tip to the
        workspace)."""
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != self.action_space.shape or not np.isfinite(a).all():
            raise InputError(f"action {action!r}: expected {self.action_space.shape[0]} finite values in [-1, 1]")
        a = np.minimum(np.maximum(a, -1.0), 1.0)  # np.clip costs several times more on three numbers
        w = self.workspace
        tip = np.minimum(np.maximum(self.tip + a[:2] * (self.max_speed * self.dt), w[:2]), w[2:])
        yaw, jaw, k = self.yaw, self.jaw, 2
        if self.max_yaw_rate > 0:
            yaw = self.yaw + float(a[k]) * self.max_yaw_rate * self.dt
            k += 1
        if self.jaw_open > 0:
            jaw = 0.5 * (float(a[k]) + 1.0) * self.jaw_open
        return tip, yaw, jaw

    def step(self, action: Any):
        self.tip, self.yaw, self.jaw = self.command(action)
        report = self.sim.step(self.pose(), jaw=self.jaw if self.jaw_open > 0 else None)
        self.report = report
        self.steps += 1
        obs = self._observation()
        info = self._info(report, obs["achieved_goal"], obs["desired_goal"])
        # from the observation's float32 goals, as a replay buffer relabelling them recomputes it, bit for bit
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))
        if self.render_mode == "human":
            self.render()
        return obs, reward, bool(report.diverged), False, info

    # ------------------------------------------------------------------------------------------ what is seen
    def points(self) -> np.ndarray:
        """The tracked points now (K, 2) [m], without noise."""
        return self.point_matrix @ self.sim.state.particle_q

    def _observation(self) -> dict[str, np.ndarray]:
        pts = self.points()
        if self.noise > 0:
            pts = pts + self.np_random.normal(0.0, self.noise, pts.shape)
        r = self.report
        held = 0 if r is None else r.grasped.shape[0]
        f = (0.0, 0.0) if r is None else r.reaction_force
        torque = 0.0 if r is None else r.reaction_torque
        vec = np.empty(pts.size + len(TOOL_FIELDS), dtype=np.float32)
        vec[:pts.size] = pts.ravel()
        vec[pts.size:] = (self.tip[0], self.tip[1], self.yaw, self.jaw, held, f[0], f[1], torque)
        achieved = self.achieved()
        return {"observation": vec, "achieved_goal": achieved.astype(np.float32),
                "desired_goal": self.goal.astype(np.float32)}

    def _info(self, r: StepReport | None, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> dict[str, Any]:
        """What a step did beyond the reward: success, distance, energy terms, penetration, convergence. The same
        keys and types every step (the reset's are zeros), so vector envs and Minari stack them."""
        d = float(self.distance(achieved_goal, desired_goal))
        info = {"is_success": bool(d <= self.tolerance), "distance": d}
        if r is None:
            info.update(energy=0.0, energy_inertial=0.0, energy_strain=0.0, energy_attach=0.0, force=0.0,
                        penetration=0.0, n_penetrating=0, converged=True, solve_iterations=0, diverged=False,
                        grasped=0)
            return info
        e = r.energy
        strain = e.strain if e.strain is not None else e.spring + e.area
        info.update(energy=e.scene_total, energy_inertial=float(e.inertial.sum()), energy_strain=float(strain.sum()),
                    energy_attach=0.0 if e.attach is None else float(e.attach.sum()),
                    force=math.hypot(float(r.reaction_force[0]), float(r.reaction_force[1])),
                    penetration=float(r.penetration_depth), n_penetrating=int(r.n_penetrating),
                    converged=bool(r.solve_converged), solve_iterations=int(r.solve_iterations),
                    diverged=bool(r.diverged), grasped=int(r.grasped.shape[0]))
        return info

    # ------------------------------------------------------------------------------------------ pictures
    def frame_goals(self) -> np.ndarray:
        """The goal points drawn in a frame (G, 2) [m]."""
        return self.goal.reshape(-1, 2)

    def frame_achieved(self) -> np.ndarray:
        """The achieved points drawn in a frame (G, 2) [m]."""
        return self.achieved().reshape(-1, 2)

    def frame_bounds(self) -> tuple[float, float, float, float]:
        """The frame's view (x_min, x_max, y_min, y_max) [m]."""
        w = self.workspace
        return float(w[0]), float(w[2]), float(w[1]), float(w[3])

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: make the environment with render_mode='rgb_array'")
            return None
        from .frame import draw_frame  # noqa: PLC0415  (OpenCV drawing only when rendering)

        frame = draw_frame(self.sim.model, self.sim.state.particle_q, self.sim.tool, self.pose(), self.jaw,
                           goals=self.frame_goals(), achieved=self.frame_achieved(), points=self.points(),
                           held=None if self.report is None else self.report.grasped, bounds=self.frame_bounds(),
                           size=(self.width, self.height), tolerance=self.tolerance)
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            from .frame import FrameWindow  # noqa: PLC0415

            self._window = FrameWindow(f"tissue_sim_ros: {type(self).__name__}", self.width, self.height)
        self._window.show(frame)
        return None

    def close(self) -> None:
        if self._window is not None:
            self._window.close()
            self._window = None
        super().close()

    def describe(self) -> dict[str, Any]:
        """What the environment runs (for a benchmark's or a dataset's record): scene, particles, solver."""
        p = self.sim.params
        return {"scene": self.scene or "paper", "particles": int(self.sim.model.n_particles),
                "spacing": float(self.config.flat()["spacing"]), "material": p.material, "method": p.method,
                "contact_model": p.contact_model, "dt": self.dt, "tracked_points": int(self.point_w.shape[0])}


def embedding_matrix(tris: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    """The (P, n) matrix B of embedded points (triangles ``tris`` (P, 3), weights ``w`` (P, 3)): points = B @ x."""
    b = np.zeros((tris.shape[0], n))
    np.add.at(b, (np.repeat(np.arange(tris.shape[0]), 3), tris.ravel()), w.ravel())
    return b


def as_points(values: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    """Points (P, 2) float64 from any nested sequence; InputError when they are not finite pairs."""
    try:
        a = np.asarray(values, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise InputError(f"goal {values!r}: expected (x, y) points in m") from None
    if not np.isfinite(a).all():
        raise InputError(f"goal {values!r}: expected finite (x, y) points in m")
    return a
