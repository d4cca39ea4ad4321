"""The methods: paper PBD, XPBD (Gauss-Seidel / Jacobi), substepped XPBD.

A Solver is made once per Model (it holds workspaces: multipliers, scratch
arrays, constraint colouring) and steps ``(state_in, state_out, contacts, dt)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .collision import Contacts
from .model import Model, State


@dataclass
class SolveInfo:
    """What a solve hands back to the Simulation."""

    x_pred: np.ndarray
    """Full-step predicted positions x* [m], shape (N, 2) (including the paper contact's displacement)."""
    contact_dx: np.ndarray | None
    """Sum of the contact model's position corrections per particle over the step [m], shape (N, 2), or None."""
    residual: float
    """RMS constraint violation after the solve (edges relative to rest length, areas relative to rest area)."""


class Solver:
    """Steps a Model: prediction, constraint solve, velocity update, boundary lines."""

    def __init__(self, model: Model) -> None:
        self.model = model

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        raise NotImplementedError("Solver.step: implemented with the numba kernels (issue 3)")
