r"""Attachment constraints: particles held to targets by zero-length XPBD springs (a grasper's jaws).

The solvers receive, per step, on :class:`~tissue_sim_ros.core.contact.collision.Contacts`:

* ``attach_idx`` (K,) int64: the held particles;
* ``attach_target`` (K, 2) float64 [m]: where each is held, in the world, at the end of the step (the tool's
  pose at the end of the step composed with the particle's coordinates in the tool frame, stored when the
  jaw closed);
* ``attach_compliance`` [m/N]: the springs' compliance c (stiffness 1/c).

Energy of one attachment: E = 1/(2 c) |x - t|^2; its force on the particle is (t - x) / c and the particle's on
the tool (x - t) / c.

Projection (XPBD, Macklin et al. 2016, eqs. 17-18), one scalar constraint per axis, C_d = x_d - t_d (so the
spring never has a direction to lose at zero length): with alpha~ = c / h^2 for a (sub)step h and the
multiplier lambda_d (zeroed at the start of every substep, as the other multipliers)::

    d lambda_d = (-C_d - alpha~ lambda_d) / (w + alpha~)       w: the particle's inverse mass this step
    lambda_d  += d lambda_d
    x_d       += w d lambda_d

A particle held by something else this step (w = 0: pinned, or the paper contact's held set) is not moved.
The solvers call :func:`project_attachments` after the tool's contact projection in every iteration.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def project_attachments(x: np.ndarray, inv_mass: np.ndarray, attach_idx: np.ndarray, attach_target: np.ndarray,
                        alpha_tilde: float, lam_attach: np.ndarray) -> None:
    """One Gauss-Seidel pass over the attachments (module docstring), in place.

    x : (N, 2) float64 positions [m], updated; inv_mass : (N,) [1/kg]; attach_idx : (K,) int64;
    attach_target : (K, 2) float64 [m]; alpha_tilde = compliance / h^2 [kg^-1]; lam_attach : (K, 2) float64,
    the multipliers, updated.
    """
    for k in range(attach_idx.shape[0]):
        i = attach_idx[k]
        w = inv_mass[i]
        if w == 0.0:
            continue
        for d in range(2):
            c = x[i, d] - attach_target[k, d]
            dlam = (-c - alpha_tilde * lam_attach[k, d]) / (w + alpha_tilde)
            lam_attach[k, d] += dlam
            x[i, d] += w * dlam


def attachment_energy(x: np.ndarray, particle_body: np.ndarray, attach_idx: np.ndarray, attach_target: np.ndarray,
                      compliance: float, out: np.ndarray) -> None:
    """Add each body's attachment energy sum 1/(2 c) |x_i - t_i|^2 [J] into ``out`` (B,)."""
    if attach_idx.shape[0] == 0:
        return
    d = x[attach_idx] - attach_target
    np.add.at(out, particle_body[attach_idx], 0.5 * (d * d).sum(axis=1) / compliance)


def attachment_wrench(x: np.ndarray, attach_idx: np.ndarray, attach_target: np.ndarray, compliance: float,
                      centre: tuple[float, float]) -> tuple[np.ndarray, float]:
    """The held particles' pull on the tool: force sum (x_i - t_i) / c [N], (2,), and its torque about
    ``centre`` [N m] (at the targets, where the springs meet the tool)."""
    if attach_idx.shape[0] == 0:
        return np.zeros(2), 0.0
    f = (x[attach_idx] - attach_target) / compliance
    r = attach_target - np.asarray(centre, dtype=np.float64)
    return f.sum(axis=0), float(np.sum(r[:, 0] * f[:, 1] - r[:, 1] * f[:, 0]))
