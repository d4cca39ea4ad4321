"""An independent static reference: linear plane-stress FEM (scikit-fem, P2 triangles).

The simulator's material model (``material: neo_hookean``) must converge, run to
rest under refinement, to the static answer of continuum elasticity. This
module computes that answer with a different method and a different code: a
standard displacement finite element method with quadratic (P2) triangles,
assembled by scikit-fem on its own structured meshes. It imports nothing from
``tissue_sim_ros.core`` (a test checks), so a bug in the simulator's kernels,
meshes, mass lumping or units cannot leak into its own reference.

Equations (SI units: lengths m, Young's modulus E Pa, thickness h m, density
rho kg/m^3, gravity g m/s^2; y points up, gravity is (0, -g)):

* small strain, ``eps(u) = (grad u + grad u^T) / 2``;
* plane stress (a thin sheet, sigma_zz = 0), Hooke's law in 2D with the
  plane-stress Lame parameters

      lambda = E nu / (1 - nu^2),      mu = E / (2 (1 + nu)),
      sigma  = 2 mu eps + lambda tr(eps) I;

* weak form over the sheet's mid-plane Omega, per unit area times thickness h:

      h int_Omega sigma(u) : eps(v) dA = h int_Omega rho b . v dA    for all v,

  with the body force per unit mass ``b = (0, -g)``; ``h`` is kept in both
  sides so the stiffness is in N/m and a reaction force comes out in N.

Problems (a rectangle [x0, x0 + width] x [y0, y0 + height]):

* **hanging strip**: top edge clamped (u = 0), the rest free, gravity. Sag =
  the downward displacement ``-u_y``: its area mean (``int -u_y dA / A``), its
  maximum (over the P2 nodes) and an evaluator at arbitrary points.
* **flat punch**: bottom edge clamped, the top pushed down by ``depth`` by a
  rigid frictionless plate (``u_y = -depth`` on the top edge, ``u_x`` free),
  sides free, no gravity. Punch force = the plate's total vertical force on
  the tissue in N, from the reaction ``K u - f`` summed over the top edge's
  vertical degrees of freedom (reported as a positive compressive force).

Each problem is solved on a sequence of uniformly refined meshes (the element
size halved each level) until the reported quantities change by less than
``rtol`` (0.05 % by default) between two levels. The FEM's own error is
estimated from the last three levels: the changes fall geometrically (by the
ratio r = 2^p, p about 1.4 here, below P2's 3 because of the stress
singularities at the clamped corners), so the error of the finest level is
about the last change / (r - 1) (``rel_error``, reported with every answer).

Linear elasticity is the small-strain limit of every hyperelastic model: the
simulator's Neo-Hookean answer differs from it by O(strain), so benchmarks
keep the strain small (reported as ``strain``, the nominal strain) and say so.

Closed forms the tests check (P2 reproduces them to round-off, because the
exact fields are polynomials of degree <= 2):

* uniaxial compression (``flat_punch(..., bottom="slip")``: bottom held only
  vertically, so nothing resists the lateral bulge): uniform stress
  ``sigma_yy = -E depth / height``, force ``E width h depth / height``;
* hanging bar with nu = 0: ``sigma_yy = rho g (H - s)``, ``u_y(s) = -rho g
  (H s - s^2 / 2) / E`` with ``s`` the distance below the top edge, ``u_x = 0``.

Needs the optional ``fem`` extra (``pip install .[fem]``; the ``test`` extra
has it too).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError  # the one bad-input type; no physics from core is used

#: Default relative change between two refinement levels at which the FEM counts as converged.
DEFAULT_RTOL = 5e-4


def _skfem():
    """Import scikit-fem (an optional dependency) with a clear message when it is missing."""
    try:
        import skfem
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the FEM reference needs scikit-fem: pip install 'tissue_sim_ros[fem]'") from exc
    return skfem


def plane_stress_lame(young_modulus: float, poisson_ratio: float) -> tuple[float, float]:
    """Plane-stress Lame parameters (lambda, mu) [Pa]: lambda = E nu / (1 - nu^2), mu = E / (2 (1 + nu))."""
    E, nu = float(young_modulus), float(poisson_ratio)
    if not (math.isfinite(E) and E > 0):
        raise InputError(f"young_modulus must be a finite number > 0 Pa, got {young_modulus!r}")
    if not (math.isfinite(nu) and 0.0 <= nu < 0.5):
        raise InputError(f"poisson_ratio must be in [0, 0.5), got {poisson_ratio!r}")
    return E * nu / (1.0 - nu * nu), E / (2.0 * (1.0 + nu))


@dataclass(frozen=True)
class Level:
    """One refinement level of a converged FEM solve."""

    n_x: int
    """Element columns (each square cell is split into two P2 triangles)."""
    n_y: int
    """Element rows."""
    n_dofs: int
    """Degrees of freedom (2 per P2 node)."""
    values: dict
    """The reported quantities on this level (name -> value, SI units)."""


@dataclass
class FemSolution:
    """A converged static FEM solution and its reported quantities.

    Lengths in m, forces in N. ``rel_change`` is the largest relative change of
    the reported quantities between the last two refinement levels: the FEM's
    own error estimate.
    """

    problem: str
    """``"hanging_strip"`` or ``"flat_punch"``."""
    params: dict
    """The problem's inputs (geometry, material, load)."""
    values: dict
    """Reported quantities on the finest level: ``mean_sag``, ``max_sag`` [m] or ``force`` [N], ``strain`` [-]."""
    rel_change: float
    """Largest relative change of ``values`` between the last two levels."""
    rel_error: float
    """Estimated relative error of the finest level: the last change divided by (r - 1), r the observed
    ratio of two successive changes (the geometric tail of the remaining refinements), or the last change
    itself when fewer than three levels were solved or the changes did not fall."""
    levels: list[Level] = field(default_factory=list)
    """Every level solved, coarse to fine."""
    _basis: object = field(default=None, repr=False)
    _u: np.ndarray | None = field(default=None, repr=False)

    def __getattr__(self, name: str):
        # convenience: solution.mean_sag, solution.force ...
        values = self.__dict__.get("values", {})
        if name in values:
            return values[name]
        raise AttributeError(name)

    def displacement(self, points: np.ndarray) -> np.ndarray:
        """Displacement u [m] at points (N, 2) [m] inside or on the rectangle, shape (N, 2)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        x0, y0 = self.params["origin"]
        w, h = self.params["width"], self.params["height"]
        # points on the boundary: nudge a hair inside so the element finder always finds a cell
        eps = 1e-12 * max(w, h)
        pts = np.column_stack([np.clip(pts[:, 0], x0 + eps, x0 + w - eps), np.clip(pts[:, 1], y0 + eps, y0 + h - eps)])
        out = np.empty_like(pts)
        for c, (sub, idx) in enumerate(zip(self._basis.split_bases(), self._basis.split_indices())):
            out[:, c] = sub.probes(pts.T) @ self._u[idx]
        return out


# ----------------------------------------------------------------------------- assembly


def _forms(lam: float, mu: float, thickness: float, rho_g: float):
    skfem = _skfem()
    from skfem.helpers import ddot, sym_grad, trace

    @skfem.BilinearForm
    def stiffness(u, v, w):
        # h * sigma(u) : eps(v), sigma = 2 mu eps + lambda tr(eps) I (plane stress Lame parameters)
        eu = sym_grad(u)
        ev = sym_grad(v)
        return thickness * (2.0 * mu * ddot(eu, ev) + lam * trace(eu) * trace(ev))

    @skfem.LinearForm
    def weight(v, w):
        # h * rho * b . v with b = (0, -g)
        return -thickness * rho_g * v[1]

    return stiffness, weight


def _mesh(width: float, height: float, origin: tuple[float, float], n_x: int, n_y: int):
    skfem = _skfem()
    x0, y0 = origin
    xs = np.linspace(x0, x0 + width, n_x + 1)
    ys = np.linspace(y0, y0 + height, n_y + 1)
    mesh = skfem.MeshTri.init_tensor(xs, ys)
    tol = 1e-9 * max(width, height)
    return mesh.with_boundaries({
        "top": lambda x: np.abs(x[1] - (y0 + height)) < tol,
        "bottom": lambda x: np.abs(x[1] - y0) < tol,
    })


def _solve_level(problem: str, p: dict, n_x: int, n_y: int):
    skfem = _skfem()
    lam, mu = plane_stress_lame(p["young_modulus"], p["poisson_ratio"])
    mesh = _mesh(p["width"], p["height"], p["origin"], n_x, n_y)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTriP2()))
    rho_g = p["density"] * p["gravity"]
    stiffness, weight = _forms(lam, mu, p["thickness"], rho_g)
    K = stiffness.assemble(basis)
    f = weight.assemble(basis) if rho_g != 0.0 else np.zeros(basis.N)
    u = basis.zeros()
    area = p["width"] * p["height"]
    if problem == "hanging_strip":
        fixed = basis.get_dofs("top").all()
        u = skfem.solve(*skfem.condense(K, f, x=u, D=fixed))
        uy = u[basis.nodal_dofs[1]], u[basis.facet_dofs[1]]
        mean_uy = float(skfem.Functional(lambda w: w["u"][1]).assemble(basis, u=basis.interpolate(u))) / area
        values = {"mean_sag": -mean_uy, "max_sag": float(-min(uy[0].min(), uy[1].min()))}
    elif problem == "flat_punch":
        top_y = basis.get_dofs("top").all("u^2")
        if p["bottom"] == "clamped":
            bottom = basis.get_dofs("bottom").all()
        else:  # "slip": bottom held vertically only, one corner also horizontally (no rigid motion)
            bottom_y = basis.get_dofs("bottom").all("u^2")
            corner = int(np.argmin(np.hypot(mesh.p[0] - p["origin"][0], mesh.p[1] - p["origin"][1])))
            bottom = np.concatenate([bottom_y, [basis.nodal_dofs[0][corner]]])
        u[top_y] = -p["depth"]
        fixed = np.unique(np.concatenate([top_y, bottom]))
        u = skfem.solve(*skfem.condense(K, f, x=u, D=fixed))
        reaction = K @ u - f  # force the constraints exert on the tissue, per degree of freedom [N]
        values = {"force": float(-reaction[top_y].sum())}
    else:  # pragma: no cover - internal
        raise ValueError(problem)
    # the nominal strain, the size of the geometric nonlinearity a hyperelastic model adds to this linear
    # answer (the pointwise maximum is singular at the clamped corners and grows with refinement):
    # hanging, the top edge's strain rho g H / E; punch, depth / H
    if problem == "hanging_strip":
        values["strain"] = rho_g * p["height"] / p["young_modulus"]
    else:
        values["strain"] = p["depth"] / p["height"]
    return values, basis, u


def _converge(problem: str, p: dict, rtol: float, n0: int, max_levels: int) -> FemSolution:
    aspect = p["width"] / p["height"]
    levels: list[Level] = []
    prev = None
    rel = math.inf
    keys = ("mean_sag", "max_sag") if problem == "hanging_strip" else ("force",)
    for k in range(max_levels):
        n_y = n0 * 2 ** k
        n_x = max(1, int(round(aspect * n_y)))
        values, basis, u = _solve_level(problem, p, n_x, n_y)
        levels.append(Level(n_x, n_y, basis.N, values))
        if prev is not None:
            rel = max(abs(values[q] - prev[q]) / max(abs(values[q]), 1e-300) for q in keys)
            if rel < rtol:
                break
        prev = values
    else:
        raise RuntimeError(f"FEM {problem} did not converge to rtol={rtol} in {max_levels} levels (last change {rel:.2e})")
    err = rel
    if len(levels) >= 3:
        errs = []
        for q in keys:
            a, b, c = (lv.values[q] for lv in levels[-3:])
            d1, d2 = abs(b - a), abs(c - b)
            r = d1 / d2 if d2 > 0 else math.inf
            errs.append(d2 / (r - 1.0) / abs(c) if r > 1.0 else d2 / abs(c))
        err = max(errs)
    return FemSolution(problem, dict(p), values, rel, err, levels, basis, u)


def _params(width, height, young_modulus, poisson_ratio, thickness, density, gravity, origin):
    for name, value in (("width", width), ("height", height), ("thickness", thickness)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a finite number > 0 m, got {value!r}")
    if not (math.isfinite(density) and density >= 0):
        raise InputError(f"density must be a finite number >= 0 kg/m^3, got {density!r}")
    plane_stress_lame(young_modulus, poisson_ratio)
    return {"width": float(width), "height": float(height), "young_modulus": float(young_modulus),
            "poisson_ratio": float(poisson_ratio), "thickness": float(thickness), "density": float(density),
            "gravity": float(gravity), "origin": (float(origin[0]), float(origin[1]))}


# ----------------------------------------------------------------------------- public problems


@functools.lru_cache(maxsize=32)
def hanging_strip(width: float = 0.10, height: float = 0.04, young_modulus: float = 50e3,
                  poisson_ratio: float = 0.45, thickness: float = 1e-3, density: float = 1000.0,
                  gravity: float = 9.8, origin: tuple[float, float] = (0.0, 0.0),
                  rtol: float = DEFAULT_RTOL, n0: int = 2, max_levels: int = 8) -> FemSolution:
    """Static sag of a strip hanging from its clamped top edge under its own weight.

    Defaults: a 10 cm wide, 4 cm tall strip, E 50 kPa, nu 0.45, 1 mm thick,
    1000 kg/m^3, g 9.8 m/s^2 (nominal strain rho g H / E = 0.8 %). ``gravity`` is the
    magnitude g; the load is (0, -g) per unit mass. The thickness cancels out
    of the sag (stiffness and weight both scale with it) and is kept for
    symmetry with the simulator's parameters.

    Returns a :class:`FemSolution` with ``mean_sag`` (area mean of -u_y),
    ``max_sag`` (largest -u_y) in m and ``displacement(points)``.
    """
    p = _params(width, height, young_modulus, poisson_ratio, thickness, density, gravity, origin)
    return _converge("hanging_strip", p, rtol, n0, max_levels)


@functools.lru_cache(maxsize=32)
def flat_punch(width: float = 0.10, height: float = 0.04, young_modulus: float = 50e3,
               poisson_ratio: float = 0.45, thickness: float = 1e-3, depth: float = 2e-4,
               origin: tuple[float, float] = (0.0, 0.0), bottom: str = "clamped",
               rtol: float = DEFAULT_RTOL, n0: int = 2, max_levels: int = 8) -> FemSolution:
    """Force of a rigid frictionless plate pressing the top edge down by ``depth`` [m].

    The bottom edge is clamped (``bottom="clamped"``) or held vertically only
    (``bottom="slip"``, the uniaxial closed form); the sides are free; no
    gravity. Defaults: the strip of :func:`hanging_strip`, pressed 0.2 mm
    (0.5 % of its height). Returns a :class:`FemSolution` with ``force`` [N]
    (the plate's downward push on the tissue, positive) and
    ``displacement(points)``.
    """
    if bottom not in ("clamped", "slip"):
        raise InputError(f"bottom must be 'clamped' or 'slip', got {bottom!r}")
    if not (math.isfinite(depth) and 0 < depth < height):
        raise InputError(f"depth must be in (0, height) m, got {depth!r}")
    p = _params(width, height, young_modulus, poisson_ratio, thickness, 0.0, 0.0, origin)
    p["depth"], p["bottom"] = float(depth), bottom
    return _converge("flat_punch", p, rtol, n0, max_levels)


def summary(solution: FemSolution) -> str:
    """One line per refinement level: the level's size and reported quantities."""
    lines = [f"{solution.problem}: last change {solution.rel_change:.2e}, estimated error {solution.rel_error:.2e}"]
    for lv in solution.levels:
        vals = ", ".join(f"{k}={v:.6g}" for k, v in lv.values.items())
        lines.append(f"  {lv.n_x}x{lv.n_y} cells, {lv.n_dofs} dofs: {vals}")
    return "\n".join(lines)
