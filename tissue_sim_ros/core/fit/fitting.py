"""Identify tissue parameters from a recording: least squares over rollouts, error bars, identifiability.

The unknowns are optimised in a scaled variable z: ``z = ln(value)`` for a
scale parameter (a stiffness, a modulus, a density: positive, wanted to a
relative accuracy) and ``z = value / scale`` for the others (Poisson's ratio,
a damping rate that may be 0). The residuals are simulated minus observed
tracked-point coordinates in mm over the fitted frames. The optimiser's
Jacobian is forward differences in z, the final one (error bars,
identifiability) central differences; each is one batch of candidates handed to
the :class:`~tissue_sim_ros.core.fit.tracking.TrackSimulator`.

Uncertainty (Gauss-Newton at the optimum): ``cov_z = tau s^2 (J^T J)^-1`` with
``s^2 = |r|^2 / (m - n)``; ``tau = 1 + 2 sum_k rho_k`` is the integrated
autocorrelation time of the residuals along the recording (rho_k summed while
positive), so residuals that are not white (model error that is smooth in
time, as a coarser mesh than the tissue's leaves) widen the error bars by the
factor the effective number of independent residuals falls. With a refined
scene (the same on half the mesh spacing), one rollout of it at the optimum
gives the shift the estimate would take on that mesh, ``dz = -(J^T J)^-1 J^T
(r_refined - r)``, which joins the covariance as a systematic error,
``cov_z += diag(dz^2)``: a parameter the recording tells only through what the
mesh gets wrong gets the wide error bar it deserves.

A parameter is *not identifiable*, tested in this order, when

* it has no effect on the observed points: changing it by a plausible amount
  (a factor 2, or a quarter of its bounds; one rollout each) moves them by less than
  EFFECT_FRACTION of the residual's RMS, i.e. less than the noise and the
  model's own error could hide (Poisson's ratio where no observed point feels
  it; Young's modulus where the tool prescribes every displacement and no
  weight or inertia counts; anything when the tool never touches a tissue at
  rest);
* only a combination with another is determined: their estimates correlate
  by MAX_CORRELATION or more (Young's modulus and density enter the motion
  only as E / rho);
* its 95% interval is wider than that plausible amount.

It is then held at its starting value, the others refitted, and reported with
the reason instead of a number. The forward-difference step is 10% of a scale
parameter (``diff_step`` 0.1): contact makes a rollout rough at the micrometre
level (two rollouts with the same E / rho, the same motion in exact
arithmetic, differ there), which a small step turns into Jacobian noise.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError
from .tracking import SimulatedTracks, TrackSimulator

#: Parameters a fit knows how to scale: name -> (kind, scale or None, default bounds or None).
#: ``log``: z = ln(value), bounds default to value / 100 .. value * 100; ``lin``: z = value / scale.
KNOWN_PARAMETERS: dict[str, tuple[str, float | None, tuple[float, float] | None]] = {
    "young_modulus": ("log", None, None),
    "poisson_ratio": ("lin", 0.4, (0.0, 0.49)),
    "thickness": ("log", None, None),
    "density": ("log", None, None),
    "damping": ("lin", 2.0, (0.0, 50.0)),
    "stiffness_spring": ("log", None, None),
    "stiffness_area": ("log", None, None),
    "mass_per_area": ("log", None, None),
    "mass": ("log", None, None),
    "k_spring": ("lin", 0.4, (0.0, 1.0)),
    "k_area": ("lin", 0.4, (0.0, 1.0)),
}

#: A parameter whose plausible change moves the points by less than this fraction of the residual's RMS has
#: no effect the recording can tell from its noise and the model's error.
EFFECT_FRACTION = 0.2
#: Two parameters whose estimates correlate this strongly are determined only as a combination.
MAX_CORRELATION = 0.95
#: A scale parameter is identified when its 95% interval is within this factor either way.
MAX_FACTOR_95 = 2.0
#: Any other parameter is identified when its 95% half-width is below this fraction of its bounds' span.
MAX_SPAN_FRACTION_95 = 0.25
Z95 = 1.959964


@dataclass(frozen=True)
class FitParameter:
    """One unknown: its name, start value, bounds and scaling."""

    name: str
    initial: float
    lower: float
    upper: float
    kind: str = "log"
    """``log`` (z = ln value) or ``lin`` (z = value / scale)."""
    scale: float = 1.0

    def to_z(self, value: float) -> float:
        return math.log(value) if self.kind == "log" else value / self.scale

    def from_z(self, z: float) -> float:
        return math.exp(z) if self.kind == "log" else z * self.scale

    @property
    def z_bounds(self) -> tuple[float, float]:
        return self.to_z(self.lower), self.to_z(self.upper)


def make_parameter(name: str, initial: float, bounds: tuple[float, float] | None = None,
                   kind_of: str | None = None) -> FitParameter:
    """A :class:`FitParameter` with the scaling of :data:`KNOWN_PARAMETERS` (log for other positive values).

    ``kind_of``: the parameter whose scaling to use (``young_modulus`` for ``young_modulus@1``).
    """
    if not (isinstance(initial, (int, float)) and not isinstance(initial, bool) and math.isfinite(initial)):
        raise InputError(f"parameter {name}={initial!r}: expected a finite number to start the fit from")
    kind, scale, default_bounds = KNOWN_PARAMETERS.get(kind_of or name,
                                                       ("log" if initial > 0 else "lin", None, None))
    if kind == "log" and initial <= 0:
        raise InputError(f"parameter {name}={initial!r}: expected a value > 0 to fit (it is fitted on a log scale)")
    if bounds is None:
        bounds = default_bounds if default_bounds is not None else (
            (initial / 100.0, initial * 100.0) if kind == "log" else (initial - 10 * (scale or 1.0), initial + 10 * (scale or 1.0)))
    lo, hi = float(bounds[0]), float(bounds[1])
    if not (lo < hi) or (kind == "log" and lo <= 0):
        raise InputError(f"bounds of {name} {lo}:{hi}: expected lower < upper" + (" and lower > 0" if kind == "log" else ""))
    if not lo <= initial <= hi:
        raise InputError(f"parameter {name}={initial}: the start value is outside its bounds {lo}:{hi}")
    return FitParameter(name=name, initial=float(initial), lower=lo, upper=hi, kind=kind,
                        scale=float(scale) if scale else (abs(initial) if kind == "lin" and initial else 1.0))


@dataclass
class ParameterEstimate:
    """The outcome for one parameter."""

    name: str
    initial: float
    value: float | None
    """The fitted value; None when it is not identifiable."""
    sigma: float | None
    """One standard deviation [the parameter's unit] (delta method for log-scaled ones)."""
    low95: float | None
    high95: float | None
    identifiable: bool
    reason: str = ""
    """Why it is not identifiable (empty when it is)."""
    mesh_shift: float | None = None
    """How far the estimate moves on a mesh of half the spacing [the parameter's unit]; part of ``sigma``."""

    def as_dict(self) -> dict:
        return {"name": self.name, "initial": self.initial, "value": self.value, "sigma": self.sigma,
                "low95": self.low95, "high95": self.high95, "identifiable": self.identifiable, "reason": self.reason,
                "mesh_shift": self.mesh_shift}


@dataclass
class CostSlice:
    """The cost along one parameter through the optimum, the others held."""

    name: str
    values: np.ndarray
    cost: np.ndarray
    """0.5 sum r^2 [mm^2] at each value."""


@dataclass
class FitResult:
    """What a fit found."""

    estimates: list[ParameterEstimate]
    values: dict[str, float]
    """Every fitted parameter's final value (the start value for those not identifiable)."""
    rms_fit_mm: float
    rms_holdout_mm: float | None
    cost: float
    """0.5 sum r^2 over the fitted frames [mm^2]."""
    n_residuals: int
    tau: float
    """Integrated autocorrelation time of the residuals (1 for white residuals)."""
    singular_values: np.ndarray
    """Relative singular values of the scaled Jacobian (largest 1)."""
    jacobian: np.ndarray
    """d residual [mm] / d z at the optimum, shape (m, n)."""
    covariance_z: np.ndarray | None
    n_rollouts: int
    n_iterations: int
    wall_time: float
    optimizer: str
    message: str
    contact_steps: int
    """Steps with contact in the final rollout of the fitted part."""
    simulated: np.ndarray | None = None
    """Simulated points over the whole recording with the final values, shape (F, P, 2)."""
    slices: list[CostSlice] = field(default_factory=list)

    def estimate(self, name: str) -> ParameterEstimate:
        return next(e for e in self.estimates if e.name == name)


def autocorrelation_time(res: np.ndarray) -> float:
    """Integrated autocorrelation time of residual series, res shape (F, C) (time along axis 0).

    tau = 1 + 2 sum_{k>=1} rho_k with rho_k = sum_t r_t r_{t+k} / sum_t r_t^2 over all C series (residuals
    of a fit are zero-mean under the model, so they are not centred), summed while positive (truncated at
    the first negative rho, as Geyer's initial positive sequence).
    """
    r = np.where(np.isfinite(res), res, 0.0)
    # not centred: a residual's offset that lasts the whole recording (a point the model puts a little off
    # throughout, the typical model error) is exactly the correlation that counts
    f = r.shape[0]
    var = (r * r).sum()
    if f < 3 or var <= 0:
        return 1.0
    tau = 1.0
    for k in range(1, f // 2):
        rho = float((r[k:] * r[:-k]).sum() / var)
        if rho <= 0:
            break
        tau += 2.0 * rho
    return tau


class FitProblem:
    """Residuals of a recording's fitted frames as a function of the scaled unknowns z."""

    def __init__(self, simulator: TrackSimulator, observed: np.ndarray, parameters: Sequence[FitParameter],
                 n_fit_frames: int, fixed: Mapping[str, float] | None = None, diff_step: float = 0.1) -> None:
        self.simulator = simulator
        self.observed = observed
        self.parameters = list(parameters)
        self.n_fit = int(n_fit_frames)
        self.fixed = dict(fixed or {})
        self.diff_step = float(diff_step)
        self._cache: dict[bytes, tuple[np.ndarray, SimulatedTracks]] = {}
        obs = observed[1:self.n_fit]  # frame 0 binds the points: zero residual by construction
        self._mask = np.isfinite(obs)
        self.n_residuals = int(self._mask.sum())

    def values(self, z: np.ndarray) -> dict[str, float]:
        out = dict(self.fixed)
        out.update({p.name: p.from_z(float(zi)) for p, zi in zip(self.parameters, z)})
        return out

    def residual_of(self, tracks: SimulatedTracks) -> np.ndarray:
        sim = tracks.points[1:self.n_fit]
        r = (sim - self.observed[1:self.n_fit]) * 1e3
        return r[self._mask]

    def evaluate(self, zs: Sequence[np.ndarray]) -> list[tuple[np.ndarray, SimulatedTracks]]:
        """Residuals [mm] and tracks of several z at once (one batch to the simulator; cached)."""
        keys = [np.asarray(z, dtype=np.float64).tobytes() for z in zs]
        todo = [i for i, k in enumerate(keys) if k not in self._cache]
        # drop duplicates within the batch
        first: dict[bytes, int] = {}
        for i in todo:
            first.setdefault(keys[i], i)
        idx = list(first.values())
        if idx:
            runs = self.simulator.simulate([self.values(zs[i]) for i in idx], self.n_fit)
            for i, run in zip(idx, runs):
                self._cache[keys[i]] = (self.residual_of(run), run)
        return [self._cache[k] for k in keys]

    def residual(self, z: np.ndarray) -> np.ndarray:
        return self.evaluate([z])[0][0]

    def jacobian(self, z: np.ndarray, central: bool = False) -> np.ndarray:
        """Forward (or ``central``) differences in z, one batch; a forward step goes away from the nearer bound.

        The optimiser uses forward differences (n + 1 rollouts, the centre cached); the error bars and the
        identifiability use central ones (2 n rollouts): they cancel the curvature, so two parameters that
        enter only as a ratio (E / rho) give exactly opposite columns.
        """
        z = np.asarray(z, dtype=np.float64)
        n = len(self.parameters)
        eye = np.eye(n)
        h = self.diff_step
        cols = []
        if central:
            zs = []
            spans = []
            for j, p in enumerate(self.parameters):
                lo, hi = p.z_bounds
                a, b = max(lo, z[j] - h), min(hi, z[j] + h)
                zs += [z + (a - z[j]) * eye[j], z + (b - z[j]) * eye[j]]
                spans.append(b - a)
            out = self.evaluate(zs)
            for j in range(n):
                cols.append((out[2 * j + 1][0] - out[2 * j][0]) / spans[j])
        else:
            steps = []
            for j, p in enumerate(self.parameters):
                lo, hi = p.z_bounds
                step = h if z[j] + h <= hi else -h
                if z[j] + step < lo:
                    step = h
                steps.append(step)
            out = self.evaluate([z] + [z + steps[j] * eye[j] for j in range(n)])
            r0 = out[0][0]
            cols = [(out[j + 1][0] - r0) / steps[j] for j in range(n)]
        if not cols:
            return np.zeros((self.n_residuals, 0))
        return np.column_stack(cols)


def _covariance(jac: np.ndarray, r: np.ndarray, params: Sequence[FitParameter], tau: float
                ) -> tuple[np.ndarray | None, np.ndarray]:
    """Gauss-Newton covariance of z and the relative singular values of the scaled J."""
    n_params = len(params)
    if jac.size == 0:
        return None, np.zeros(0)
    sv = np.linalg.svd(scaled_jacobian(params, jac), compute_uv=False)
    rel = sv / sv[0] if sv[0] > 0 else np.zeros_like(sv)
    dof = max(1, r.size - n_params)
    s2 = float(r @ r) / dof
    try:
        cov = tau * s2 * np.linalg.pinv(jac.T @ jac, rcond=1e-12)
    except np.linalg.LinAlgError:
        return None, rel
    return cov, rel


def plausible_range(p: FitParameter) -> float:
    """The change of z that matters for a parameter: a factor 2 (log) or a quarter of its bounds' span (lin)."""
    return math.log(MAX_FACTOR_95) if p.kind == "log" else MAX_SPAN_FRACTION_95 * (p.upper - p.lower) / p.scale


def scaled_jacobian(params: Sequence[FitParameter], jac: np.ndarray) -> np.ndarray:
    """J with each column times its parameter's :func:`plausible_range`: comparable across units."""
    return jac * np.array([plausible_range(p) for p in params])[None, :] if len(params) else jac


def plausible_effect(problem: "FitProblem", z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """RMS move of the fitted residuals [mm] when each parameter alone changes by its :func:`plausible_range`.

    Measured by one rollout per parameter (a batch), toward the inside of its bounds: the slope of a rough
    rollout is no guide to a parameter that barely matters (contact moves points by micrometres at random
    when anything changes, which a difference quotient divides by a small step).
    """
    zs = []
    for j, p in enumerate(problem.parameters):
        lo, hi = p.z_bounds
        d = plausible_range(p)
        zz = z.copy()
        zz[j] = z[j] + d if z[j] + d <= hi or z[j] - d < lo else z[j] - d
        zz[j] = min(max(zz[j], lo), hi)
        zs.append(zz)
    out = problem.evaluate(zs)
    m = max(1, r.size)
    return np.array([math.sqrt(float((rj - r) @ (rj - r)) / m) for rj, _ in out])


def _identifiability(params: Sequence[FitParameter], effect: np.ndarray, cov: np.ndarray | None, r: np.ndarray,
                     contact_steps: int, cov_stat: np.ndarray | None = None) -> list[str]:
    """A reason per parameter ('' = identified); see the module docstring for the tests, in this order.

    ``effect``: :func:`plausible_effect` [mm RMS per residual]; ``cov``: the covariance of z with the mesh's
    systematic part, ``cov_stat`` without it (the correlations are the recording's, default ``cov``).
    """
    cov_stat = cov if cov_stat is None else cov_stat
    n = len(params)
    reasons = [""] * n
    if n == 0:
        return reasons
    m = max(1, r.size)
    resid_rms = math.sqrt(float(r @ r) / m)
    no_touch = "; the tool never touches the tissue in the fitted part" if contact_steps == 0 else ""
    for j, p in enumerate(params):
        if effect[j] <= EFFECT_FRACTION * resid_rms:
            change = "a factor 2" if p.kind == "log" else f"{plausible_range(p) * p.scale:.3g}"
            reasons[j] = (f"has no effect on the observed points: changing it by {change} moves them by "
                          f"{effect[j]:.3g} mm RMS, under {EFFECT_FRACTION:g} of the residual's {resid_rms:.3g} mm"
                          f"{no_touch}")
    if cov is not None and cov_stat is not None:
        sc = np.sqrt(np.maximum(np.diag(cov_stat), 0.0))
        effective = [not w for w in reasons]
        combined = [""] * n
        for j in range(n):
            if not effective[j]:
                continue
            corr = [(params[i].name, cov_stat[i, j] / (sc[i] * sc[j])) for i in range(n)
                    if i != j and effective[i] and sc[i] > 0 and sc[j] > 0]
            strong = [(nm, c) for nm, c in corr if abs(c) >= MAX_CORRELATION]
            if strong:
                combined[j] = ("only a combination with " + ", ".join(f"{nm} (correlation {c:.3f})" for nm, c in strong)
                               + " is determined: fit one with the other held" + no_touch)
        reasons = [w or c for w, c in zip(reasons, combined)]
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        for j, p in enumerate(params):
            if reasons[j] or Z95 * sd[j] <= plausible_range(p):
                continue
            if p.kind == "log":
                what = f"the recording determines it only within a factor {math.exp(Z95 * sd[j]):.3g} (95%)"
            else:
                what = f"the recording determines it only to +-{Z95 * sd[j] * p.scale:.3g} (95%)"
            reasons[j] = what + no_touch
    return reasons


def _least_squares(problem: FitProblem, z0: np.ndarray, max_nfev: int, on_iter: Callable[[float], None] | None
                   ) -> tuple[np.ndarray, int, str]:
    from scipy.optimize import least_squares  # noqa: PLC0415  (scipy is slow to import; only fits need it)

    lo = np.array([p.z_bounds[0] for p in problem.parameters])
    hi = np.array([p.z_bounds[1] for p in problem.parameters])
    count = [0]

    def fun(z: np.ndarray) -> np.ndarray:
        r = problem.residual(z)
        count[0] += 1
        if on_iter is not None:
            on_iter(0.5 * float(r @ r))
        return r

    res = least_squares(fun, z0, jac=problem.jacobian, bounds=(lo, hi), method="trf", x_scale=1.0,
                        xtol=1e-4, ftol=1e-6, gtol=1e-8, max_nfev=max_nfev)
    return res.x, int(res.nfev), str(res.message)


def _cma(problem: FitProblem, z0: np.ndarray, max_nfev: int, on_iter: Callable[[float], None] | None,
         seed: int) -> tuple[np.ndarray, int, str]:
    try:
        import cma  # noqa: PLC0415  (optional extra: pip install '.[fit]')
    except ModuleNotFoundError:
        raise InputError("--optimizer cma needs the 'cma' package: pip install 'tissue_sim_ros[fit]'") from None
    lo = [p.z_bounds[0] for p in problem.parameters]
    hi = [p.z_bounds[1] for p in problem.parameters]
    es = cma.CMAEvolutionStrategy(list(z0), 0.3, {"bounds": [lo, hi], "seed": seed, "verbose": -9,
                                                  "maxfevals": max_nfev, "tolfun": 1e-6, "tolx": 1e-4})
    n = 0
    while not es.stop():
        zs = [np.asarray(z) for z in es.ask()]
        out = problem.evaluate(zs)
        costs = [0.5 * float(r @ r) for r, _ in out]
        n += len(zs)
        es.tell([list(z) for z in zs], costs)
        if on_iter is not None:
            on_iter(min(costs))
    return np.asarray(es.result.xbest, dtype=np.float64), n, ", ".join(f"{k}={v}" for k, v in es.stop().items())


def fit(simulator: TrackSimulator, observed: np.ndarray, parameters: Sequence[FitParameter], *, n_fit_frames: int,
        optimizer: str = "least_squares", max_nfev: int = 60, diff_step: float = 0.1, seed: int = 0,
        slices: int = 9, slice_sigmas: float = 3.0, on_iter: Callable[[float], None] | None = None,
        refined: TrackSimulator | None = None) -> FitResult:
    """Fit ``parameters`` so that the simulated tracked points match ``observed`` over the first frames.

    Parameters
    ----------
    simulator : TrackSimulator
        Rolls out candidate parameter values.
    observed : (F, P, 2) tracked points [m] (NaN: not seen).
    parameters : the unknowns (start values, bounds, scaling).
    n_fit_frames : frames 0 .. n_fit_frames-1 are fitted; the rest is held out.
    optimizer : ``least_squares`` (scipy, trust region reflective) or ``cma`` (CMA-ES, for a rough cost).
    slices : points per 1D cost slice through the optimum (0: none), spanning +- slice_sigmas sigma (at least
        +-10% or +-0.02 scale units).
    refined : the same scene on a finer mesh (optional): one rollout of it at the optimum tells how far the
        estimate would move with the discretisation; that shift joins the error bars (``mesh_shift``).
    """
    if optimizer not in ("least_squares", "cma"):
        raise InputError(f"optimizer={optimizer!r}: expected least_squares or cma")
    start = time.perf_counter()
    params = list(parameters)
    if not params:
        raise InputError("nothing to fit: expected at least one parameter")
    n_total = observed.shape[0]
    if not 2 <= n_fit_frames <= n_total:
        raise InputError(f"{n_fit_frames} fitted frames of {n_total}: expected at least 2")
    held: dict[str, float] = {}
    reasons: dict[str, str] = {}
    active, rollouts, nfev_total, message, problem, z = params, 0, 0, "", None, None
    for _attempt in range(len(params) + 1):
        problem = FitProblem(simulator, observed, active, n_fit_frames, fixed=held, diff_step=diff_step)
        if problem.n_residuals < len(active) + 1:
            raise InputError(f"{problem.n_residuals} observed coordinates in the fitted part: too short to fit "
                             f"{len(active)} parameter(s)")
        z0 = np.array([p.to_z(p.initial) for p in active])
        if optimizer == "least_squares":
            z, nfev, message = _least_squares(problem, z0, max_nfev, on_iter)
        else:
            z, nfev, message = _cma(problem, z0, max_nfev, on_iter, seed)
        nfev_total += nfev
        r, run = problem.evaluate([z])[0]
        jac = problem.jacobian(z, central=True)
        res_frames = _residual_frames(problem, run)
        tau = autocorrelation_time(res_frames)
        cov, rel_sv = _covariance(jac, r, active, tau)
        shift = None
        cov_stat = cov
        if refined is not None and cov is not None:
            # the same fit on a refined mesh would move z by -(J^T J)^-1 J^T (r_refined - r): the estimate's
            # dependence on the discretisation, added to the error bars as a systematic error
            fine = problem.residual_of(refined.simulate([problem.values(z)], n_fit_frames)[0])
            shift = -np.linalg.lstsq(jac, fine - r, rcond=None)[0]
            cov = cov + np.diag(shift ** 2)
            rollouts += 1
        why = _identifiability(active, plausible_effect(problem, z, r), cov, r, run.contact_steps, cov_stat)
        rollouts += len(problem._cache)
        if not any(why):
            break
        for p, w in zip(active, why):
            if w:
                held[p.name] = p.initial
                reasons[p.name] = w
        active = [p for p in active if p.name not in held]
        if not active:
            break
    assert problem is not None and z is not None
    if not active:
        # nothing identifiable: report the residual at the start values
        problem = FitProblem(simulator, observed, [], n_fit_frames, fixed=held, diff_step=diff_step)
        z = np.zeros(0)
        r, run = problem.evaluate([z])[0]
        jac = np.zeros((r.size, 0))
        tau = autocorrelation_time(_residual_frames(problem, run))
        cov, rel_sv, shift = None, np.zeros(0), None
        rollouts += 1
    final = problem.values(z)
    estimates = _estimates(params, held, reasons, active, z, cov, shift)
    # the whole recording with the final values: the fitted part and the held-out part
    full = simulator.simulate([final], n_total)[0]
    rollouts += 1
    from .tracking import rms_mm  # noqa: PLC0415

    rms_fit = rms_mm(full.points[1:n_fit_frames], observed[1:n_fit_frames])
    rms_hold = rms_mm(full.points[n_fit_frames:], observed[n_fit_frames:]) if n_fit_frames < n_total else None
    result = FitResult(
        estimates=estimates, values=final, rms_fit_mm=rms_fit, rms_holdout_mm=rms_hold, cost=0.5 * float(r @ r),
        n_residuals=int(r.size), tau=tau, singular_values=rel_sv, jacobian=jac, covariance_z=cov,
        n_rollouts=rollouts, n_iterations=nfev_total, wall_time=0.0, optimizer=optimizer, message=message,
        contact_steps=run.contact_steps, simulated=full.points)
    if slices > 0 and active:
        result.slices = cost_slices(problem, z, cov, slices, slice_sigmas)
        result.n_rollouts += sum(len(s.values) for s in result.slices)
    result.wall_time = time.perf_counter() - start
    return result


def _residual_frames(problem: FitProblem, run: SimulatedTracks) -> np.ndarray:
    """Residuals [mm] as a (frames, coordinates) table for the autocorrelation (NaN where not observed)."""
    f = problem.n_fit
    r = (run.points[1:f] - problem.observed[1:f]) * 1e3
    return r.reshape(r.shape[0], -1)


def cost_slices(problem: FitProblem, z: np.ndarray, cov: np.ndarray | None, n: int, sigmas: float) -> list[CostSlice]:
    """The cost along each parameter through ``z`` (one batch for all slices)."""
    grids = []
    for j, p in enumerate(problem.parameters):
        sz = math.sqrt(max(0.0, cov[j, j])) if cov is not None else 0.0
        half = max(sigmas * sz, 0.1 if p.kind == "log" else 0.2)
        lo, hi = p.z_bounds
        g = np.clip(z[j] + np.linspace(-half, half, n), lo, hi)
        grids.append(g)
    zs = []
    for j, g in enumerate(grids):
        for v in g:
            zz = z.copy()
            zz[j] = v
            zs.append(zz)
    out = problem.evaluate(zs)
    slices = []
    for j, (p, g) in enumerate(zip(problem.parameters, grids)):
        costs = np.array([0.5 * float(r @ r) for r, _ in out[j * n:(j + 1) * n]])
        slices.append(CostSlice(p.name, np.array([p.from_z(float(v)) for v in g]), costs))
    return slices


def _estimates(params: Sequence[FitParameter], held: dict[str, float], reasons: dict[str, str],
               active: Sequence[FitParameter], z: np.ndarray, cov: np.ndarray | None,
               shift: np.ndarray | None) -> list[ParameterEstimate]:
    """Each parameter's estimate from the fit's scaled optimum ``z`` and its covariance (95% bounds, the mesh's
    shift), or the reason it was held at its start value."""
    estimates = []
    for p in params:
        if p.name in held:
            estimates.append(ParameterEstimate(p.name, p.initial, None, None, None, None, False, reasons[p.name]))
            continue
        j = [q.name for q in active].index(p.name)
        zj = float(z[j])
        sz = math.sqrt(max(0.0, cov[j, j])) if cov is not None else float("nan")
        value = p.from_z(zj)
        if p.kind == "log":
            sigma, lo95, hi95 = value * sz, math.exp(zj - Z95 * sz), math.exp(zj + Z95 * sz)
        else:
            sigma, lo95, hi95 = sz * p.scale, value - Z95 * sz * p.scale, value + Z95 * sz * p.scale
        mesh_shift = None
        if shift is not None:
            mesh_shift = value * math.expm1(float(shift[j])) if p.kind == "log" else float(shift[j]) * p.scale
        estimates.append(ParameterEstimate(p.name, p.initial, value, sigma, lo95, hi95, True, mesh_shift=mesh_shift))
    return estimates
