"""The tissue's reaction on the tool after a step: the contact's pushes and the grasp's pulls, as forces.

A push dx of particle i that the tool made over a step of ``den`` [s^2] is a force m_i dx / den on the particle, and
its reaction -m_i dx / den on the tool (the projection contact: den = dt h, the mean over the substeps of h; the
paper contact's held displacements: den = dt^2). A particle held to the tool by an attachment of compliance c
pulls it with (x_i - t_i) / c. The torques are about the tool's centre, each particle's written out so the caller
sums them as it always has (NumPy's pairwise sum): :meth:`Simulation.step
<tissue_sim_ros.core.sim.simulation.Simulation.step>` and the fused rollout (``core/sim/fused.py``) share these
kernels. Sums over particles start from 0.0 and add in particle order, as NumPy's reduction along them does.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def touched_particles(contact_dx: np.ndarray, out: np.ndarray) -> int:
    """The particles the contact pushed (a nonzero row of ``contact_dx`` (N, 2)), in order, into ``out`` (N,)
    int64; returns how many."""
    n = 0
    for i in range(contact_dx.shape[0]):
        if contact_dx[i, 0] != 0.0 or contact_dx[i, 1] != 0.0:
            out[n] = i
            n += 1
    return n


@njit(cache=True, nogil=True)
def push_reaction(idx: np.ndarray, dx: np.ndarray, by_particle: bool, mass: np.ndarray, den: float, x: np.ndarray,
                  centre: tuple, torque_each: np.ndarray) -> tuple[float, float]:
    """Sum over the pushed particles ``idx`` (K,) of -m dx / den [N]; each one's torque about ``centre`` (x, y)
    [m] with the particles at ``x`` into ``torque_each[:K]`` [N m].

    ``dx``: the pushes [m], a row per particle (``by_particle``: (N, 2), row idx[k]) or per entry of ``idx``
    ((K, 2)). K = 0: (0, 0).
    """
    fx = 0.0
    fy = 0.0
    for k in range(idx.shape[0]):
        i = idx[k]
        row = i if by_particle else k
        fxk = -mass[i] * dx[row, 0] / den
        fyk = -mass[i] * dx[row, 1] / den
        fx += fxk
        fy += fyk
        torque_each[k] = (x[i, 0] - centre[0]) * fyk - (x[i, 1] - centre[1]) * fxk
    return fx, fy


@njit(cache=True, nogil=True)
def attach_reaction(idx: np.ndarray, x: np.ndarray, target: np.ndarray, compliance: float, centre: tuple,
                    torque_each: np.ndarray) -> tuple[float, float]:
    """The held particles' pull on the tool, sum (x_i - t_i) / c [N] over ``idx`` (K,) with targets (K, 2) [m];
    each one's torque about ``centre`` at its target (where the spring meets the tool) into
    ``torque_each[:K]`` [N m]."""
    fx = 0.0
    fy = 0.0
    for k in range(idx.shape[0]):
        i = idx[k]
        fxk = (x[i, 0] - target[k, 0]) / compliance
        fyk = (x[i, 1] - target[k, 1]) / compliance
        fx += fxk
        fy += fyk
        torque_each[k] = (target[k, 0] - centre[0]) * fyk - (target[k, 1] - centre[1]) * fxk
    return fx, fy
