"""Calibrate XPBD's physical stiffnesses to the paper's PBD: equal static sag of the reference strip.

The reference strip: ``mesh_rectangle(1.0, 0.5, 0.05)`` (21 x 11 = 231
particles), pinned along its top and bottom rows, m = 1e-4 kg, g = -9.8,
dt = 0.01 s, 30 iterations, sagging under gravity for 3 s from rest. The sag
is the mean downward displacement of the free particles, averaged over the
last 0.5 s (steps 251-300) so a residual oscillation does not bias it.

XPBD's stiffnesses keep the ratio stiffness_area / stiffness_spring fixed
(``AREA_TO_SPRING``) and are scaled together by bisection on log(stiffness)
until XPBD's sag equals PBD's (Table I: k_spring 0.15, k_area 1) at 30
iterations. Run ``python -m tissue_sim_ros.bench.calibration`` to reproduce
the numbers in ``docs/calibration.md``.
"""
from __future__ import annotations

import math
import sys
from typing import Any, Mapping

import numpy as np

from ..core.config import method_options, resolve_config
from ..core.mesh import mesh_rectangle
from ..core.sim.simulation import Simulation

#: stiffness_area [N/m^3] per stiffness_spring [N/m] kept during calibration (the issue's 1e5 / 1e2).
AREA_TO_SPRING = 1.0e3
STEPS = 300
AVERAGE_LAST = 50


#: The reference strip's parameters (module docstring): Table I, top and bottom rows pinned (no lines).
STRIP = {"mass": 1e-4, "mass_per_area": 0.0, "gravity": -9.8, "dt": 0.01, "damping": 0.0, "k_spring": 0.15,
         "k_area": 1.0, "pin_y_bottom": 1e-9, "pin_y_top": 0.5 - 1e-9, "boundary_y_bottom": math.nan,
         "boundary_y_top": math.nan}


def strip_sag(values: Mapping[str, Any], steps: int = STEPS,
              average_last: int = AVERAGE_LAST) -> tuple[float, float, bool]:
    """(mean sag [m], max sag [m], diverged) of the reference strip after ``steps`` steps.

    ``values``: the method's parameters (:func:`~tissue_sim_ros.core.config.method_options`, stiffnesses) over
    :data:`STRIP`. Mean and max over the free particles, averaged over the last ``average_last`` steps.
    """
    mesh = mesh_rectangle(1.0, 0.5, 0.05)
    sim = Simulation.from_config(resolve_config({**STRIP, **values}, source="the calibration strip"), mesh=mesh)
    model = sim.model
    free = ~model.particle_pinned
    means, maxes = [], []
    for k in range(steps):
        report = sim.step()
        if report.diverged:
            return math.nan, math.nan, True
        if k >= steps - average_last:
            sag = model.particle_q0[free, 1] - sim.state.particle_q[free, 1]
            means.append(sag.mean())
            maxes.append(sag.max())
    return float(np.mean(means)), float(np.mean(maxes)), False


def calibrate(iterations: int = 30, rounds: int = 30) -> dict[str, float]:
    """Bisection on log(stiffness_spring) for XPBD's mean sag = PBD's at ``iterations``."""
    target, target_max, _ = strip_sag(method_options("pbd", iterations))

    def sag(ks: float) -> float:
        return strip_sag({**method_options("xpbd", iterations), "stiffness_spring": ks,
                          "stiffness_area": AREA_TO_SPRING * ks})[0]

    lo, hi = 0.1, 1.0e4  # sag(lo) > target > sag(hi)
    for _ in range(rounds):
        mid = math.sqrt(lo * hi)
        if sag(mid) > target:
            lo = mid
        else:
            hi = mid
    ks = math.sqrt(lo * hi)
    return dict(pbd_mean_sag=target, pbd_max_sag=target_max, stiffness_spring=ks,
                stiffness_area=AREA_TO_SPRING * ks, xpbd_mean_sag=sag(ks))


def main() -> int:
    print("PBD (Table I) mean / max sag of the reference strip by iteration count:")
    for it in (5, 30, 100):
        mean, mx, div = strip_sag(method_options("pbd", it))
        print(f"  {it:>3} iterations: {1e3 * mean:.4f} / {1e3 * mx:.4f} mm")
    print("XPBD at Table I's k read as stiffnesses (0.15 N/m, 1 N/m^3):")
    for it in (5, 30, 100):
        mean, mx, div = strip_sag({**method_options("xpbd", it), "stiffness_spring": 0.15, "stiffness_area": 1.0})
        print(f"  {it:>3} iterations: {1e3 * mean:.1f} / {1e3 * mx:.1f} mm" + (" (diverged)" if div else ""))
    result = calibrate()
    print(f"calibrated: stiffness_spring = {result['stiffness_spring']:.4g} N/m, "
          f"stiffness_area = {result['stiffness_area']:.4g} N/m^3; XPBD sag {1e3 * result['xpbd_mean_sag']:.4f} mm "
          f"vs PBD {1e3 * result['pbd_mean_sag']:.4f} mm")
    ks = float(f"{result['stiffness_spring']:.2g}")
    print(f"rounded defaults {ks:g} / {AREA_TO_SPRING * ks:g}, sag by iteration count (XPBD mean / max):")
    for it in (5, 30, 100, 1000):
        mean, mx, _ = strip_sag({**method_options("xpbd", it), "stiffness_spring": ks,
                                 "stiffness_area": AREA_TO_SPRING * ks})
        print(f"  {it:>4} iterations: {1e3 * mean:.4f} / {1e3 * mx:.4f} mm")
    mean, mx, _ = strip_sag({**method_options("xpbd_substep", 30), "stiffness_spring": ks,
                             "stiffness_area": AREA_TO_SPRING * ks})
    print(f"  30 substeps x 1 iteration: {1e3 * mean:.4f} / {1e3 * mx:.4f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
