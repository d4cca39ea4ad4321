"""``tissue-sim bench spacing``: how the paper's constraint material changes with the mesh spacing.

A strip of ``--width`` x ``--height`` (``mesh_rectangle``: right triangles of
area h^2 / 2, alternating diagonals) at each spacing h, the XPBD stiffnesses
of ``config/tissue_sim.yaml``. Measured from the implementation's own energy
(:func:`~tissue_sim_ros.core.physics.energy.energy_terms`) and exact static solves
(:func:`~tissue_sim_ros.bench.reference.reference_step`):

* ``spring_modulus`` [N/m]: spring energy per area of a uniaxial stretch eps in
  x, divided by eps^2 / 2. Springs E = 1/2 k (l - l0)^2: a spring of length
  ~h stretches by ~eps h (energy ~ k eps^2 h^2) and there are ~1/h^2 of them
  per area, so the modulus does not depend on h; on this lattice it is
  3/2 k (horizontal edges: k, diagonals: k / 2), reached as the boundary's
  share shrinks;
* ``area_modulus`` [N/m]: area energy per area of an isotropic dilation eps,
  divided by eps^2 / 2. Areas E = 1/2 k_a (A - A0)^2 with A0 = h^2 / 2:
  (A - A0) = 2 eps A0, so the energy per triangle is ~k_a eps^2 h^4 over
  ~2 / h^2 triangles per area: 2 k_a h^2, four times softer per halving;
* ``mass_per_area`` [kg/m^2] with Table I's per-particle mass (m per vertex:
  ~m / h^2, four times heavier per halving) and with ``mass_per_area``
  (lumped from an areal density: the same at every h);
* ``sag`` [m]: mean drop of the bottom row of the strip hanging from its top
  row under gravity, at static equilibrium (Newton on the implicit Euler
  energy with dt = 3 s, whose inertia term m/dt^2 = 1e-5 of the springs'
  stiffness; converged to 1e-14 of the starting gradient), for: springs and
  areas with the per-particle mass, the same with the areal density, and
  springs alone with the areal density.

Writes ``spacing.csv`` and ``spacing.png`` and prints the table.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import resolve_config
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.physics.energy import energy_terms
from ..core.physics.model import Model, SimParams
from .accuracy import format_table, write_csv
from .reference import reference_step

STRAIN = 1e-3
"""Strain of the stretch and dilation probes (small: the moduli are those of the linearised energy)."""
STATIC_DT = 3.0
"""dt of the static solve [s]: the inertia term m/dt^2 (~1e-5 N/m per particle) is negligible next to k."""


def _moduli(model: Model) -> tuple[float, float]:
    """(spring, area) effective moduli [N/m] of the model's rest mesh, from its own energy terms."""
    q0 = model.particle_q0
    lo, hi = q0.min(axis=0), q0.max(axis=0)
    area = float(np.prod(hi - lo))
    dt2 = model.params.dt ** 2
    stretched = q0.copy()
    stretched[:, 0] = lo[0] + (q0[:, 0] - lo[0]) * (1.0 + STRAIN)
    spring = energy_terms(model, stretched, stretched).spring.sum() / dt2
    dilated = lo + (q0 - lo) * (1.0 + STRAIN)
    area_e = energy_terms(model, dilated, dilated).area.sum() / dt2
    scale = area * STRAIN ** 2 / 2.0
    return float(spring / scale), float(area_e / scale)


def _sag(mesh: Any, params: SimParams, height: float) -> tuple[float, bool]:
    """Mean drop [m] of the bottom row of ``mesh`` hanging from its top row, at static equilibrium."""
    p = replace(params, dt=STATIC_DT, boundary_y_top=height - 1e-9, boundary_y_bottom=float("nan"), damping=0.0)
    model = Model.from_mesh(mesh, p)
    result = reference_step(model, model.state(), dt=STATIC_DT, x0=model.particle_q0.copy(), rtol=1e-14,
                            max_iterations=200)
    bottom = np.isclose(model.particle_q0[:, 1], model.particle_q0[:, 1].min())
    return float(-(result.particle_q[bottom, 1] - model.particle_q0[bottom, 1]).mean()), bool(result.converged)


def measure(spacings: list[float], width: float = 0.4, height: float = 0.2, mass_per_area: float = 0.0506,
            base: SimParams | None = None) -> list[dict[str, Any]]:
    """One row per spacing: particles, moduli, mass per area and the three sags (see the module doc)."""
    base = base or resolve_config({"method": "xpbd"}).sim
    rows = []
    for h in spacings:
        mesh = mesh_rectangle(width, height, h)
        table_i = replace(base, mass_per_area=0.0)
        areal = replace(base, mass_per_area=mass_per_area)
        springs_only = replace(areal, stiffness_area=0.0)
        model = Model.from_mesh(mesh, table_i)
        spring_mod, area_mod = _moduli(model)
        sag_table, ok1 = _sag(mesh, table_i, height)
        sag_areal, ok2 = _sag(mesh, areal, height)
        sag_springs, ok3 = _sag(mesh, springs_only, height)
        rows.append({
            "spacing_m": h, "particles": model.n_particles, "spring_modulus_N_per_m": spring_mod,
            "area_modulus_N_per_m": area_mod, "area_modulus_over_2ka_h2": area_mod / (2 * base.stiffness_area * h * h),
            "mass_per_area_table_i": float(model.particle_mass.sum()) / (width * height),
            "mass_per_area_areal": float(Model.from_mesh(mesh, areal).particle_mass.sum()) / (width * height),
            "sag_table_i_m": sag_table, "sag_areal_m": sag_areal, "sag_springs_only_areal_m": sag_springs,
            "static_converged": ok1 and ok2 and ok3,
        })
    return rows


#: mesh spacings [m] of the sweep
SPACINGS = (0.05, 0.025, 0.0125, 0.00625)


def run(out: str | Path, *, spacings: Sequence[float] = SPACINGS, width: float = 0.4, height: float = 0.2,
        mass_per_area: float = 0.0506, quick: bool = False) -> int:
    """Measure the moduli, mass and sag at every spacing; print, write spacing.csv/png into ``out``; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    spacings : sequence of float
        Mesh spacings [m] (``quick``: 0.1 and 0.05).
    width, height : float
        The strip [m].
    mass_per_area : float
        Areal density of the areal-mass runs [kg/m^2] (default: the default scene's).
    quick : bool
        Two coarse spacings (smoke test).
    """
    spacings = [0.1, 0.05] if quick else list(spacings)
    if not spacings or any(not (h > 0) for h in spacings):
        raise InputError(f"--spacings {spacings}: expected spacings > 0 m")
    if not (width > 0 and height > 0 and mass_per_area > 0):
        raise InputError("--width, --height and --mass-per-area: expected values > 0")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = measure(sorted(spacings, reverse=True), width, height, mass_per_area)
    print(format_table(rows, ["spacing_m", "particles", "spring_modulus_N_per_m", "area_modulus_N_per_m",
                              "area_modulus_over_2ka_h2", "mass_per_area_table_i", "mass_per_area_areal",
                              "sag_table_i_m", "sag_areal_m", "sag_springs_only_areal_m", "static_converged"]))
    write_csv(out / "spacing.csv", rows)
    _plot(out / "spacing.png", rows)
    print(f"wrote {out / 'spacing.csv'} and {out / 'spacing.png'}")
    return 0


def _plot(path: Path, rows: list[dict[str, Any]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    h = [r["spacing_m"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
    ax = axes[0]
    ax.loglog(h, [r["spring_modulus_N_per_m"] for r in rows], "o-", label="springs")
    ax.loglog(h, [r["area_modulus_N_per_m"] for r in rows], "s-", label="areas (~ h^2)")
    ax.set(xlabel="spacing h [m]", ylabel="effective modulus [N/m]", title="stiffness")
    ax = axes[1]
    ax.loglog(h, [r["mass_per_area_table_i"] for r in rows], "o-", label="Table I: m per particle (~ 1/h^2)")
    ax.loglog(h, [r["mass_per_area_areal"] for r in rows], "s-", label="mass_per_area")
    ax.set(xlabel="spacing h [m]", ylabel="mass per area [kg/m^2]", title="mass")
    ax = axes[2]
    for key, label in (("sag_table_i_m", "springs + areas, Table I mass"), ("sag_areal_m", "springs + areas, areal"),
                       ("sag_springs_only_areal_m", "springs only, areal")):
        ax.loglog(h, [r[key] for r in rows], "o-", label=label)
    ax.set(xlabel="spacing h [m]", ylabel="sag of the bottom row [m]", title="hanging strip, static")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
