"""Model building: pinned sets, rest lengths and areas, and the per-particle vs areal-density mass."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.sim.simulation import Simulation


def test_paper_mass_is_per_particle():
    m = Model.from_mesh(mesh_rectangle(1.0, 0.5, 0.1), SimParams())
    np.testing.assert_array_equal(m.particle_mass, 1e-4)


def test_areal_density_lumps_a_third_of_each_triangle_to_its_corners():
    mesh = mesh_rectangle(1.0, 0.5, 0.1)
    m = Model.from_mesh(mesh, SimParams(mass_per_area=0.05))
    # the masses add up to density x area: sum_i m_i = rho * sum_t A_t
    assert m.particle_mass.sum() == pytest.approx(0.05 * 0.5, rel=1e-12)
    # alternating diagonals: a corner vertex touches one or two triangles, an interior one four or eight
    # (each 0.005 m^2)
    assert m.particle_mass.min() == pytest.approx(0.05 * 0.005 / 3)
    assert m.particle_mass.max() == pytest.approx(0.05 * 8 * 0.005 / 3)
    free = ~m.particle_pinned
    np.testing.assert_allclose(m.particle_inv_mass[free], 1.0 / m.particle_mass[free])


def test_areal_density_makes_the_sag_independent_of_the_mesh():
    """A strip hanging between two lines, springs only (2D spring networks have a spacing-independent modulus):
    with per-particle mass every refinement quadruples the mass and the sag; with an areal density it does not."""
    def sag(spacing: float, density: float) -> float:
        p = SimParams(method="xpbd", stiffness_area=0.0, mass_per_area=density, iterations=60,
                      boundary_y_top=0.49, boundary_y_bottom=0.01)
        model = Model.from_mesh(mesh_rectangle(1.0, 0.5, spacing), p)
        sim = Simulation(model)
        for _ in range(200):
            sim.step()
        mid = ~model.particle_pinned & (np.abs(model.particle_q0[:, 1] - 0.25) < 0.5 * spacing + 1e-9)
        return float((model.particle_q0[mid, 1] - sim.state.particle_q[mid, 1]).mean())

    per_particle = sag(0.05, 0.0) / sag(0.1, 0.0)
    density = sag(0.05, 0.05) / sag(0.1, 0.05)
    assert per_particle > 3.0  # measured 4.1: four times the particles, four times the weight
    assert 0.9 < density < 1.25  # measured 1.08


def test_bad_density_is_named():
    with pytest.raises(InputError, match="mass_per_area"):
        SimParams(mass_per_area=-1.0)


def test_simparams_is_made_from_its_rows():
    """One home per parameter: each row of SIM_PARAMETERS is a field (its default) and its check."""
    import math
    import pickle
    from dataclasses import fields, replace

    from tissue_sim_ros.core.physics.params import SIM_PARAMETERS

    assert [(f.name, f.default) for f in fields(SimParams)] == [(p.name, p.default) for p in SIM_PARAMETERS]
    lines = dict(boundary_y_top=0.4, boundary_y_bottom=0.0, pin_y_top=0.4, pin_y_bottom=0.0, wall_y_top=0.5,
                 wall_y_bottom=-0.1)  # set: a NaN read back is another NaN, and NaN != NaN
    p = SimParams(dt=0.02, method="xpbd", **lines)
    back = pickle.loads(pickle.dumps(p))
    assert type(back) is SimParams and back == p and hash(back) == hash(p) and back.k_spring_effective == 13.0
    assert p.with_(iterations=5).iterations == 5 and SimParams() == SimParams()
    with pytest.raises(InputError, match=r"parameter iterations=0: expected at least 1 solver iteration"):
        replace(p, iterations=0)
    with pytest.raises(TypeError):
        SimParams(1e-4)  # keyword only: the fields follow the table, not an order to rely on
    # every value's type before any value's range: the NaN is named, not the dt it precedes in the table
    with pytest.raises(InputError, match=r"^parameter gravity=nan: expected a finite number$"):
        SimParams(dt=-1.0, gravity=math.nan)
    with pytest.raises(InputError, match=r"^parameter wall_y_top=0.1: expected a line above wall_y_bottom=0.3$"):
        SimParams(wall_y_top=0.1, wall_y_bottom=0.3)
    with pytest.raises(InputError, match=r"grasp_open_angle=0.1: expected an angle > grasp_close_angle=0.2 rad"):
        SimParams(grasp_open_angle=0.1)
