"""Whether a run held: the checks that tell a broken simulation from a working one, step by step.

The benchmarks find where each method fails with them (``bench/failures.py`` adds the solver's convergence);
the experiments and the demo use them to say in their summaries, and their exit codes, that a run collapsed or
blew up instead of printing its numbers as if it had not (:class:`RunHealth`). The checks, each a plain
function on arrays, applied after every step by :class:`FailureMonitor`, which keeps the first failure:

* ``nonfinite``: NaN or infinity in positions or velocities (or the Simulation reporting that it restored
  the last good state);
* ``energy_growth``: the tissue's kinetic energy growing without bound, i.e. beyond ``energy_factor`` times
  what the scene can plausibly put in (all mass moving at the fastest tool speed so far plus free fall since
  the start);
* ``inverted``: a triangle whose signed area stays <= 0 for ``inverted_steps`` consecutive steps (a transient
  flip that the signed area constraint undoes is not a failure; the paper's |area| constraint keeps it);
* ``collapsed``: a large share of the triangles inverted at one step, the tissue folded onto itself (its
  triangles flip back and forth from step to step, so the consecutive-steps test above misses it);
* ``overstrained``: the median edge strain beyond what any soft tissue takes before it tears, i.e. most of
  the tissue, not the few edges a tool or a grasp stretches locally;
* ``tunnelling``: a movable particle whose path relative to the tool went right through the tool within one
  step (the tool passed through tissue); how deep particles sit inside the tool is recorded too, as a
  metric. Both are the simulation's own run-time checks against the tool's exact shape
  (:func:`~tissue_sim_ros.core.contact.tool_checks.tool_checks`).

Off by default in :class:`FailureMonitor` (the benchmarks' verdicts stay what they were): ``collapsed`` and
``overstrained``; :class:`RunHealth` turns them on and leaves tunnelling out, since the paper's contact rule
lets a moving tool through the tissue by design.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .contact.tool import ToolPose, ToolShape, tool_shape_array
from .contact.tool_checks import INSIDE_TOL, tool_checks
from .mesh import signed_areas
from .physics.strain import edge_strain

if TYPE_CHECKING:
    from .physics.model import Model


@dataclass(frozen=True)
class Failure:
    """The first failure seen in a run."""

    kind: str
    """One of the kinds in the module docstring (or the benchmark's ``no_convergence``)."""
    step: int
    """Step index (1 = first step) at which it was seen; 0 for checks made outside a run."""
    detail: str
    """Human-readable numbers behind the verdict."""


def has_nonfinite(*arrays: np.ndarray) -> bool:
    """True if any array holds NaN or infinity."""
    return any(not np.isfinite(a).all() for a in arrays)


def kinetic_energy(mass: np.ndarray, velocity: np.ndarray) -> float:
    """1/2 sum m |v|^2 [J]; ``mass`` (N,) [kg], ``velocity`` (N, 2) [m/s]."""
    return 0.5 * float(np.sum(mass * np.einsum("ij,ij->i", velocity, velocity)))


def plausible_kinetic_energy(total_mass: float, tool_speed: float, gravity: float, elapsed: float,
                             floor_speed: float = 0.1) -> float:
    """Kinetic energy [J] of all mass moving at the tool's speed plus free-fall speed since t = 0.

    An upper bound on what tool and gravity can put into a tissue pinned at its
    boundaries; ``floor_speed`` [m/s] keeps the bound away from 0 at rest.
    """
    speed = max(tool_speed, 0.0) + abs(gravity) * max(elapsed, 0.0) + floor_speed
    return 0.5 * total_mass * speed * speed


def inverted_triangles(x: np.ndarray, tri_indices: np.ndarray) -> np.ndarray:
    """Indices of triangles whose signed area is <= 0 (CCW at rest), int64.

    ``x`` (N, 2) positions [m], ``tri_indices`` (T, 3) CCW at rest.
    """
    if len(tri_indices) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(~(signed_areas(x, tri_indices) > 0.0))


#: No triangles: the buried-tool test of :func:`tool_checks` is not one of these checks.
_NO_TRIANGLES = np.zeros((0, 3), dtype=np.int32)


def _tool_checks(x0: np.ndarray, x1: np.ndarray, pose0: ToolPose, pose1: ToolPose, shape: ToolShape,
                 particles: np.ndarray, inside_tol: float) -> tuple[int, float, int, int, bool]:
    """:func:`tool_checks` of ``particles`` (indices) over one step, the tool posed at ``pose0`` then ``pose1``."""
    x0 = np.ascontiguousarray(x0[particles], dtype=np.float64)
    x1 = np.ascontiguousarray(x1[particles], dtype=np.float64)
    return tool_checks(x0, x1, tool_shape_array(shape, pose0), tool_shape_array(shape, pose1), _NO_TRIANGLES,
                       inside_tol)


def _particles(n: int, movable: np.ndarray | None) -> np.ndarray:
    return np.arange(n) if movable is None else np.flatnonzero(movable)


def penetration_depth(x: np.ndarray, pose: ToolPose, shape: ToolShape, movable: np.ndarray | None = None) -> float:
    """Deepest a particle lies inside the tool [m] (0 if none is inside): minus its signed distance to the tool's
    exact shape, as the simulation reports it (``StepReport.penetration_depth``)."""
    return float(_tool_checks(x, x, pose, pose, shape, _particles(len(x), movable), INSIDE_TOL)[1])


def tunnelled_particles(x0: np.ndarray, x1: np.ndarray, pose0: ToolPose, pose1: ToolPose, shape: ToolShape,
                        movable: np.ndarray | None = None, tolerance: float = 1e-4) -> np.ndarray:
    """Particles the tool passed right through in one step (discrete contact missing them).

    A particle outside the tool at both ends of the step whose path relative to the tool (its start in the
    tool's frame at ``pose0`` to its end in the frame at ``pose1``) runs through the tool's exact shape, in on
    one side and out on the other, at least ``tolerance`` deep (so particles resting on the surface do not
    count): :func:`~tissue_sim_ros.core.contact.tool_checks.tool_checks`, as the simulation counts
    ``StepReport.n_tunnelled``. A particle that ends inside the tool is penetration (see
    :func:`penetration_depth`), not tunnelling: a slow tool sinking into tissue shows up there. For a rotating
    tool the chord approximates the relative path.

    Parameters
    ----------
    x0, x1 : ndarray, shape (N, 2), float64
        Positions at the start and the end of the step [m].
    pose0, pose1 : ToolPose
        Tool poses at the start and the end of the step.
    shape : ToolShape
    movable : ndarray, shape (N,), bool, optional
        Only these particles are checked (pinned ones cannot get out of the tool's way).
    tolerance : float
        Depth [m] a particle must reach inside the tool to count.

    Returns
    -------
    ndarray of int64, the tunnelled particles.
    """
    particles = _particles(len(x0), movable)
    if not _tool_checks(x0, x1, pose0, pose1, shape, particles, tolerance)[3]:
        return np.zeros(0, dtype=np.int64)
    # the kernel counts; which particles it counted, one by one (a step where the tool went through tissue)
    return np.array([i for i in particles
                     if _tool_checks(x0, x1, pose0, pose1, shape, np.array([i]), tolerance)[3]], dtype=np.int64)


class FailureMonitor:
    """Applies the run checks after every step and keeps the first failure.

    Parameters
    ----------
    model : Model
        For masses, triangles and which particles are movable.
    tool : ToolShape, optional
        Needed for the tunnelling check.
    energy_factor : float
        Kinetic energy above this times :func:`plausible_kinetic_energy` is a failure.
    inverted_steps : int
        Consecutive steps a triangle must stay inverted to count.
    tunnel_tolerance : float
        Depth [m] inside the tool a path must reach to count as tunnelling.
    collapse_fraction : float, optional
        At least this share of the triangles inverted at one step is ``collapsed``; None: not checked.
    strain_limit : float, optional
        A median |edge strain| above this is ``overstrained``; None: not checked.
    """

    def __init__(self, model: "Model", tool: ToolShape | None = None, energy_factor: float = 100.0,
                 inverted_steps: int = 5, tunnel_tolerance: float = 1e-4, collapse_fraction: float | None = None,
                 strain_limit: float | None = None) -> None:
        self.model = model
        self.collapse_fraction = collapse_fraction
        self.strain_limit = strain_limit
        self.max_median_strain = 0.0
        """Largest median |edge strain| seen so far (measured only with ``strain_limit``)."""
        self.tool = tool
        self.energy_factor = float(energy_factor)
        self.inverted_steps = int(inverted_steps)
        self.tunnel_tolerance = float(tunnel_tolerance)
        self.mass = np.asarray(model.particle_mass)
        self.total_mass = float(self.mass[np.asarray(model.particle_inv_mass) > 0].sum())
        self.movable = np.asarray(model.particle_inv_mass) > 0
        self._movable = np.flatnonzero(self.movable)
        self._inverted_run = np.zeros(model.n_triangles, dtype=np.int64)
        self.first: Failure | None = None
        self.max_kinetic_ratio = 0.0
        """Largest kinetic energy / plausible bound seen so far."""
        self.n_tunnelled = 0
        """Particles that tunnelled, summed over steps."""
        self.max_inverted = 0
        """Largest number of inverted triangles after any step."""
        self.max_penetration = 0.0
        """Deepest a particle was inside the tool at the end of a step [m] (a metric, not a failure)."""
        self.max_tool_speed = 0.0
        """Fastest tool speed so far [m/s] (the energy bound uses it: pushed tissue keeps moving after the tool stops)."""

    def observe(self, step: int, x_prev: np.ndarray, x: np.ndarray, v: np.ndarray, elapsed: float,
                diverged: bool = False, pose0: ToolPose | None = None, pose1: ToolPose | None = None,
                tool_speed: float = 0.0) -> Failure | None:
        """Check one step; return the failure found now (the first of the run is kept in ``first``).

        Parameters
        ----------
        step : int
            Index of the step just taken.
        x_prev, x : ndarray, shape (N, 2)
            Positions before and after the step [m].
        v : ndarray, shape (N, 2)
            Velocities after the step [m/s].
        elapsed : float
            Simulated time since the start [s].
        diverged : bool
            The Simulation reported NaN and restored the last good state.
        pose0, pose1 : ToolPose, optional
            Tool poses at the start and end of the step (tunnelling needs both).
        tool_speed : float
            Speed at which tool or contact rule drove particles this step [m/s], for the energy bound
            (the largest so far is used).
        """
        failure = None
        if diverged or has_nonfinite(x, v):
            failure = Failure("nonfinite", step, "NaN or inf in positions/velocities")
        else:
            ke = kinetic_energy(self.mass, v)
            self.max_tool_speed = max(self.max_tool_speed, tool_speed)
            bound = plausible_kinetic_energy(self.total_mass, self.max_tool_speed, self.model.params.gravity, elapsed)
            ratio = ke / bound
            self.max_kinetic_ratio = max(self.max_kinetic_ratio, ratio)
            inv = inverted_triangles(x, self.model.tri_indices)
            self.max_inverted = max(self.max_inverted, int(inv.size))
            run = np.zeros_like(self._inverted_run)
            run[inv] = self._inverted_run[inv] + 1
            self._inverted_run = run
            n_tunnelled = 0
            if self.tool is not None and pose0 is not None and pose1 is not None:
                n_tunnelled = _tool_checks(x_prev, x, pose0, pose1, self.tool, self._movable,
                                           self.tunnel_tolerance)[3]
                self.n_tunnelled += n_tunnelled
                self.max_penetration = max(self.max_penetration,
                                           penetration_depth(x, pose1, self.tool, self.movable))
            median_strain = self._median_strain(x)
            n_tri = len(self.model.tri_indices)
            if ratio > self.energy_factor:
                failure = Failure("energy_growth", step,
                                  f"kinetic energy {ke:.3g} J is {ratio:.3g}x the plausible {bound:.3g} J")
            elif self.collapse_fraction is not None and n_tri and inv.size >= self.collapse_fraction * n_tri:
                failure = Failure("collapsed", step, f"{inv.size} of {n_tri} triangles inverted")
            elif self.strain_limit is not None and median_strain > self.strain_limit:
                failure = Failure("overstrained", step,
                                  f"median edge strain {median_strain:.3g}, beyond {self.strain_limit:g}")
            elif n_tunnelled:
                failure = Failure("tunnelling", step, f"{n_tunnelled} particles passed through the tool")
            elif run.size and run.max() >= self.inverted_steps:
                failure = Failure("inverted", step,
                                  f"{int(np.count_nonzero(run >= self.inverted_steps))} triangles inverted "
                                  f"for {self.inverted_steps} steps")
        if failure is not None and self.first is None:
            self.first = failure
        return failure

    def _median_strain(self, x: np.ndarray) -> float:
        if self.strain_limit is None:
            return 0.0
        value = float(np.median(np.abs(edge_strain(self.model, x)))) if len(self.model.edge_indices) else 0.0
        self.max_median_strain = max(self.max_median_strain, value)
        return value


#: RunHealth's share of triangles inverted at once that is a collapse. A working run flips a few triangles
#: where a tool presses (the paper's contact rule and steep insertions: a few percent); a collapsed one most.
COLLAPSE_FRACTION = 0.25
#: RunHealth's median |edge strain| beyond which the tissue as a whole is strained past any soft tissue's
#: tearing strain (half of the edges stretched or squeezed by more than half): a tool or a grasp strains the
#: edges near it far more, but not most of the tissue.
STRAIN_LIMIT = 0.5


class RunHealth:
    """Whether a run held, for its summary and exit code: :class:`FailureMonitor` with ``collapsed`` and
    ``overstrained`` on and no tunnelling check (the paper's contact rule lets a moving tool through the tissue).

    Feed it every step: :meth:`observe_sim` with a Simulation after its step, or :meth:`observe` with positions
    alone (a recording), velocities then by finite differences.
    """

    def __init__(self, model: "Model", dt: float) -> None:
        self.monitor = FailureMonitor(model, None, collapse_fraction=COLLAPSE_FRACTION, strain_limit=STRAIN_LIMIT)
        self.dt = float(dt)
        self._prev = np.array(model.particle_q0, dtype=np.float64)

    def observe(self, step: int, x: np.ndarray, v: np.ndarray | None = None, diverged: bool = False) -> None:
        """Check step ``step`` (1 = the first) that left positions ``x`` (N, 2) [m] and velocities ``v``."""
        x = np.asarray(x, dtype=np.float64)
        if v is None:
            v = (x - self._prev) / self.dt
        with np.errstate(all="ignore"):
            self.monitor.observe(step, self._prev, x, v, step * self.dt, diverged)
        self._prev = x.copy()

    def observe_sim(self, sim: Any, report: Any) -> None:
        """Check the step ``report`` that ``sim`` (a Simulation) has just taken."""
        self.observe(report.step, sim.state.particle_q, sim.state.particle_qd, bool(report.diverged))

    @property
    def failure(self) -> Failure | None:
        """The run's first failure; None while it holds."""
        return self.monitor.first

    def verdict(self) -> str:
        """``"yes"``, or ``"no: KIND at step N (numbers)"``: the summary's line."""
        f = self.failure
        return "yes" if f is None else f"no: {f.kind} at step {f.step} ({f.detail})"


__all__ = ["COLLAPSE_FRACTION", "Failure", "FailureMonitor", "RunHealth", "STRAIN_LIMIT", "has_nonfinite",
           "inverted_triangles", "kinetic_energy", "penetration_depth", "plausible_kinetic_energy",
           "tunnelled_particles"]
