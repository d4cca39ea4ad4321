"""Failure checks for a simulation run: the ways a method or contact model breaks.

The checks on a run's arrays and their step-by-step ``FailureMonitor`` live in the core
(:mod:`tissue_sim_ros.core.health`), where the experiments' and the demo's summaries use them too. This module
adds the benchmarks' own: ``no_convergence``, the constraint residual not
falling as the iteration count grows (measured on one step by :func:`iteration_residuals`, judged by
:func:`residual_falls`; the stability bench fails a residual that rises by more than 10% from 1 to 64
iterations or turns non-finite).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..core.health import has_nonfinite

if TYPE_CHECKING:
    from ..core.sim.simulation import Simulation, StepDetail

FAILURE_KINDS = ("nonfinite", "energy_growth", "inverted", "tunnelling", "no_convergence")


def residual_falls(residuals: Sequence[float], min_drop: float = 0.5) -> bool:
    """True if the residual at the largest iteration count is at most ``min_drop`` times the first.

    ``residuals`` are measured at increasing iteration counts; NaN never passes. ``min_drop`` > 1
    tolerates a flat residual (constraints made infeasible by held particles) and fails only a rise.
    """
    r = np.asarray(residuals, dtype=np.float64)
    if len(r) < 2 or not np.isfinite(r).all():
        return False
    if r[0] == 0.0:
        return r[-1] == 0.0
    return bool(r[-1] <= min_drop * r[0])


def iteration_residuals(sim: "Simulation", detail: "StepDetail", counts: Sequence[int] = (1, 4, 16, 64),
                        field: str = "iterations") -> list[float]:
    """The solver's residual after one step solved again with each count in ``counts``.

    Parameters
    ----------
    sim : Simulation
        The run's simulation: its solver kind (and options) solves each count, made afresh
        (:meth:`~tissue_sim_ros.core.sim.simulation.Simulation.solve`); the simulation is not changed.
    detail : StepDetail
        The step (``sim.step(..., detail=True).detail``): its start state and contacts.
    counts : sequence of int
        Values of ``field`` to solve with, everything else as in ``sim.params``.
    field : str
        ``iterations`` (default) or ``substeps``.

    Returns
    -------
    list of float: the residual of each count; a non-finite result counts as inf.
    """
    out = []
    for n in counts:
        with np.errstate(all="ignore"):
            state_out, info = sim.solve(detail, **{field: int(n)})
        r = float(info.residual)
        if has_nonfinite(state_out.particle_q) or not math.isfinite(r):
            r = math.inf
        out.append(r)
    return out
