"""Tool-tissue contact: python-fcl queries, the paper's eq. (3), and projection contact.

Contract with the solver (``solvers.py``):

* ``Contacts.held_idx`` / ``held_dx``: the paper model's displaced particles and
  their displacement; the solver adds ``held_dx`` to the predicted positions
  and holds these particles (inverse mass 0) for the step.
* ``Contacts.candidates`` with ``tool_shape0`` / ``tool_shape1``: the projection
  model; inside every solver iteration the solver calls
  :func:`project_tool` on the candidate particles, with the tool posed at the
  start and the end of the (sub)step, accumulating corrections into ``dx_accum``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .model import Model, State
from .tool import ToolPose, ToolShape, ToolTwist


@dataclass
class Contacts:
    """The contact model's output for one step."""

    held_idx: np.ndarray
    """Paper model: particles displaced and held this step, shape (K,), int32."""
    held_dx: np.ndarray
    """Paper model: displacement of each held particle [m], shape (K, 2), float64."""
    candidates: np.ndarray
    """Projection model: particles that may touch the swept tool, shape (M,), int32 (empty: no projection)."""
    tool_shape0: np.ndarray
    """Tool at the start of the step, packed by :func:`~tissue_sim_ros.core.tool.tool_shape_array`, shape (7,)."""
    tool_shape1: np.ndarray
    """Tool at the end of the step, shape (7,)."""
    in_contact: np.ndarray
    """Per body: True where the tool touches, shape (B,), bool."""
    d_star: np.ndarray
    """Per body: distance tool-tissue d* [m], shape (B,), float64 (inf if not computed)."""
    touched: np.ndarray
    """Particles the contact model moved (held or projected) this step, int32; filled by the solver for projection."""

    @classmethod
    def empty(cls, n_bodies: int) -> "Contacts":
        z7 = np.zeros(7)
        return cls(np.zeros(0, np.int32), np.zeros((0, 2)), np.zeros(0, np.int32), z7, z7.copy(),
                   np.zeros(n_bodies, dtype=bool), np.full(n_bodies, np.inf), np.zeros(0, np.int32))


@njit(cache=True)
def _rounded_box_sdf(px: float, py: float, shape: np.ndarray) -> tuple[float, float, float]:
    """Signed distance from (px, py) to the posed rounded box, and its outward unit gradient."""
    c, s = shape[2], shape[3]
    dx, dy = px - shape[0], py - shape[1]
    lx, ly = c * dx + s * dy, -s * dx + c * dy  # into the tool frame
    qx, qy = abs(lx) - shape[4], abs(ly) - shape[5]
    ox, oy = max(qx, 0.0), max(qy, 0.0)
    outside = np.sqrt(ox * ox + oy * oy)
    if outside > 0.0:
        gx, gy = ox / outside, oy / outside
        d = outside
    elif qx > qy:
        gx, gy = 1.0, 0.0
        d = qx
    else:
        gx, gy = 0.0, 1.0
        d = qy
    if lx < 0.0:
        gx = -gx
    if ly < 0.0:
        gy = -gy
    # back to the world frame
    wx, wy = c * gx - s * gy, s * gx + c * gy
    return d - shape[6], wx, wy


@njit(cache=True)
def project_tool(x: np.ndarray, x_start: np.ndarray, inv_mass: np.ndarray, candidates: np.ndarray,
                 shape0: np.ndarray, shape1: np.ndarray, dx_accum: np.ndarray) -> int:
    """Push candidate particles out of the tool posed at ``shape1``; returns how many moved.

    ``x`` (N, 2) is updated in place; ``x_start`` are positions at the start of
    the (sub)step and ``shape0`` the tool there (for the swept test).
    ``dx_accum`` (N, 2) accumulates each correction (for the reaction force).
    Particles with ``inv_mass == 0`` are not moved.
    """
    moved = 0
    for k in range(candidates.shape[0]):
        i = candidates[k]
        if inv_mass[i] == 0.0:
            continue
        d, gx, gy = _rounded_box_sdf(x[i, 0], x[i, 1], shape1)
        if d < 0.0:
            x[i, 0] -= d * gx
            x[i, 1] -= d * gy
            dx_accum[i, 0] -= d * gx
            dx_accum[i, 1] -= d * gy
            moved += 1
    return moved


class ContactModel:
    """Finds tool-tissue contact each step (python-fcl) and builds :class:`Contacts`."""

    def __init__(self, model: Model, tool: ToolShape) -> None:
        self.model = model
        self.tool = tool

    def detect(self, state: State, pose0: ToolPose, pose1: ToolPose, twist: ToolTwist, dt: float) -> Contacts:
        raise NotImplementedError("ContactModel.detect: python-fcl contact (issue 4)")
