"""Walls: every particle, pinned ones too, kept in a horizontal band (the paper authors' ``collision_check``).

``wall_y_bottom`` and ``wall_y_top`` (NaN: absent) clamp y after the prediction and after every solver
iteration (the constraint methods), or bound the minimisation's active set (the material's solve). Every
solver uses them; they are not a contact model of their own.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def apply_walls(x: np.ndarray, y_bottom: float, y_top: float) -> int:
    """Keep every particle between the walls: y < y_bottom -> y_bottom, y > y_top -> y_top.

    All particles, pinned ones too (the authors' ``collision_check``); a NaN wall
    is absent. Velocities are not touched: the step's velocity update
    v = (x - x_start) / h sees the clamped positions. Returns how many moved.
    """
    has_b = not math.isnan(y_bottom)
    has_t = not math.isnan(y_top)
    moved = 0
    for i in range(x.shape[0]):
        if has_b and x[i, 1] < y_bottom:
            x[i, 1] = y_bottom
            moved += 1
        if has_t and x[i, 1] > y_top:
            x[i, 1] = y_top
            moved += 1
    return moved
