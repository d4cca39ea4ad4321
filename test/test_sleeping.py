"""Sleeping far, quiet particles (core/physics/sleeping.py): exact when nothing sleeps, frozen when all do, wakes for contact."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.contact.collision import Contacts
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.physics.solvers import ConstraintSolver, Solver
from tissue_sim_ros.core.physics.solvers.sleeping import SleepingSolver


def _model(gravity: float = -9.8) -> Model:
    return Model.from_mesh(mesh_rectangle(0.4, 0.2, 0.05),
                           SimParams(method="xpbd", gravity=gravity, boundary_y_bottom=0.01))


def test_without_sleepers_it_is_the_solver() -> None:
    model = _model()
    ref, sleepy = Solver(model, parallel=False), SleepingSolver(model, sleep_speed=0.0)  # speed >= 0: never quiet
    a, b = [model.state(), model.state()], [model.state(), model.state()]
    for _ in range(5):
        ref.step(a[0], a[1], Contacts.empty(1), 0.01)
        sleepy.step(b[0], b[1], Contacts.empty(1), 0.01)
        a.reverse()
        b.reverse()
    np.testing.assert_array_equal(a[0].particle_q, b[0].particle_q)
    assert not sleepy.sleeping.any() and sleepy.awake_constraint_fraction == 1.0


def test_quiet_tissue_falls_asleep_and_wakes_for_contact() -> None:
    model = _model(gravity=0.0)  # at rest and nothing pulls: every particle is quiet
    solver = SleepingSolver(model, wake_radius=0.06, sleep_speed=1e-6, quiet_steps=3)
    s = [model.state(), model.state()]
    for _ in range(4):
        solver.step(s[0], s[1], Contacts.empty(1), 0.01)
        s.reverse()
    assert solver.sleeping.all()
    assert solver.awake_constraint_fraction == 0.0
    np.testing.assert_array_equal(s[0].particle_q, model.particle_q0)
    # the paper contact holds a particle in the middle: it and its neighbourhood wake at once
    contacts = Contacts.empty(1)
    mid = int(np.argmin(np.hypot(*(model.particle_q0 - [0.2, 0.1]).T)))
    contacts.held_idx = np.array([mid], dtype=np.int32)
    contacts.held_dx = np.array([[0.0, -0.005]])
    solver.step(s[0], s[1], contacts, 0.01)
    assert not solver.sleeping[mid]
    near = np.hypot(*(model.particle_q0 - model.particle_q0[mid]).T) <= 0.06
    assert not solver.sleeping[near].any() and solver.sleeping[~near].any()
    assert 0.0 < solver.awake_constraint_fraction < 1.0
    # the held particle moved and pulled its awake neighbours; the sleepers did not move
    assert s[1].particle_q[mid, 1] < model.particle_q0[mid, 1]
    np.testing.assert_array_equal(s[1].particle_q[solver.sleeping], model.particle_q0[solver.sleeping])


def test_bad_settings() -> None:
    with pytest.raises(InputError):
        SleepingSolver(_model(), quiet_steps=0)
    with pytest.raises(InputError):
        SleepingSolver(_model(), wake_radius=-1.0)


def test_a_scene_asks_for_sleeping_by_parameter() -> None:
    """sleep_speed > 0 (YAML, node parameter) puts the SleepingSolver in the Simulation; 0 keeps the Solver."""
    from tissue_sim_ros.core.sim.scene import build_simulation

    mesh = mesh_rectangle(1.0, 0.5, 0.1)
    plain = build_simulation({"boundary_y_bottom": 0.01, "boundary_y_top": 0.49}, mesh=mesh)
    assert type(plain.solver) is type(Solver(plain.model)) is ConstraintSolver
    sim = build_simulation({"boundary_y_bottom": 0.01, "boundary_y_top": 0.49, "sleep_speed": 1e-3,
                            "sleep_wake_radius": 0.1}, mesh=mesh)
    assert isinstance(sim.solver, SleepingSolver) and sim.solver.wake_radius == 0.1
    for _ in range(200):  # no tool: the strip settles and falls asleep
        report = sim.step()
        assert np.isfinite(report.energy.total).all()
    assert sim.solver.sleeping[~sim.model.particle_pinned].all()


def test_the_reduced_model_keeps_the_lumped_masses() -> None:
    """With lumped masses (material or mass_per_area) a particle at the sleeping border keeps its full mass."""
    for params in (SimParams(method="xpbd", mass_per_area=0.05),
                   SimParams(material="neo_hookean", method="quasi_newton", contact_model="projection")):
        model = Model.from_mesh(mesh_rectangle(0.4, 0.2, 0.05), params)
        sleepy = SleepingSolver(model, sleep_speed=1.0)
        sleepy.sleeping = model.particle_q0[:, 0] < 0.2  # the left half asleep
        sleepy._rebuild()
        reduced = sleepy._reduced
        assert reduced.n_triangles < model.n_triangles
        np.testing.assert_array_equal(reduced.particle_mass, model.particle_mass)
        awake = ~sleepy.sleeping & ~np.asarray(model.particle_pinned)
        np.testing.assert_array_equal(reduced.particle_inv_mass[awake], 1.0 / model.particle_mass[awake])
        assert (reduced.particle_inv_mass[sleepy.sleeping] == 0).all()
