"""The solvers, one class per method, and the registry that picks one from a configuration.

=========================  ============================  =================================================
material, method           class                         what a step is
=========================  ============================  =================================================
constraints, pbd / xpbd    :class:`ConstraintSolver`     the paper's PBD or XPBD sweeps (Gauss-Seidel,
                                                         Jacobi, the authors' violated-constraint Jacobi)
neo_hookean, xpbd          :class:`MaterialXPBDSolver`   XPBD sweeps over the neo-Hookean elements
neo_hookean, quasi_newton  :class:`QuasiNewtonSolver`    the minimiser of the incremental potential, the
                                                         tool's contacts an active set
neo_hookean, ipc           :class:`IPCSolver`            the minimiser of the incremental potential with
                                                         contact barriers (the material's default)
=========================  ============================  =================================================

``sleep_speed > 0`` wraps the class in :class:`SleepingSolver`. Every class follows
:class:`~.base.SolverBase`: made once per Model with its own options, ``step(state_in, state_out, contacts, dt)``.
:func:`Solver` is the one way to make the solver a Model's parameters ask for; adding a method is a class and a
line of :data:`SOLVERS`.
"""
from __future__ import annotations

from typing import Any

from ...errors import InputError
from ..model import Model
from .base import SolveInfo, SolverBase
from .constraint import ConstraintSolver, GaussSeidel, Jacobi, ViolatedJacobi
from .ipc import IPCSolver
from .material_xpbd import MaterialXPBDSolver
from .ordering import (
    PARALLEL_MIN_PARTICLES,
    colour_constraints,
    partition_constraints,
    partition_particles,
    wavefront_order,
)
from .quasi_newton import MaterialSolve, QuasiNewtonSolver

#: (material, method) -> the solver class of that method.
SOLVERS: dict[tuple[str, str], type[SolverBase]] = {
    ("constraints", "pbd"): ConstraintSolver,
    ("constraints", "xpbd"): ConstraintSolver,
    ("neo_hookean", "xpbd"): MaterialXPBDSolver,
    ("neo_hookean", "quasi_newton"): QuasiNewtonSolver,
    ("neo_hookean", "ipc"): IPCSolver,
}

#: Every option name some solver takes (``Solver(model, **options)`` refuses others).
ALL_OPTIONS = frozenset(name for cls in SOLVERS.values() for name in cls.options)


def solver_class(model: Model) -> type[SolverBase]:
    """The class of the method ``model.params`` asks for (:data:`SOLVERS`)."""
    p = model.params
    cls = SOLVERS.get((p.material, p.method))
    if cls is None:
        known = ", ".join(f"{m} with {k}" for k, m in SOLVERS)
        raise InputError(f"method={p.method!r} with material={p.material!r}: expected one of {known}")
    return cls


def Solver(model: Model, **options: Any) -> SolverBase:  # noqa: N802  (it makes one, as the class did)
    """The solver of ``model``'s method (:func:`solver_class`), made with the options it takes.

    Options another method takes are left out (``functools.partial(Solver, parallel=False)`` serves every
    method); a name no solver takes raises InputError. Sleeping (``sleep_speed > 0``) is not applied here: the
    Simulation's default solver wraps this one (:func:`default_solver`).
    """
    unknown = sorted(set(options) - ALL_OPTIONS)
    if unknown:
        raise InputError(f"solver option {unknown[0]!r}: expected one of {', '.join(sorted(ALL_OPTIONS))}")
    cls = solver_class(model)
    return cls(model, **{k: v for k, v in options.items() if k in cls.options})


def default_solver(model: Model) -> Any:
    """The solver a Model's parameters ask for: :func:`Solver`, wrapped in :class:`SleepingSolver` when
    ``sleep_speed`` > 0."""
    if model.params.sleep_speed > 0:
        return SleepingSolver(model, wake_radius=model.params.sleep_wake_radius, sleep_speed=model.params.sleep_speed)
    return Solver(model)


from .sleeping import SleepingSolver  # noqa: E402  (it makes its inner solver with Solver)

__all__ = ["ALL_OPTIONS", "SOLVERS", "ConstraintSolver", "GaussSeidel", "IPCSolver", "Jacobi", "MaterialSolve",
           "MaterialXPBDSolver", "PARALLEL_MIN_PARTICLES", "QuasiNewtonSolver", "SleepingSolver", "SolveInfo",
           "Solver", "SolverBase", "ViolatedJacobi", "colour_constraints", "default_solver", "partition_constraints",
           "partition_particles", "solver_class", "wavefront_order"]
