"""Each solver's one compiled call per step against the same loop written in Python (``test/naive.py``), bit for
bit, and the post-solve call (finite check, energy terms, inverted triangles) against NumPy.

``ConstraintSolver.step``, ``MaterialXPBDSolver.step`` and ``QuasiNewtonSolver.step`` each run one kernel of
``core/physics/step_kernels.py`` or ``quasi_newton.quasi_newton_step``; ``naive.solver_step_reference`` calls the
same building blocks one at a time from Python. Each variant runs the same tool trajectory (experiment a's
insertion, into the tissue and out) twice, once with the solver classes' ``step`` swapped for the reference, and
every step's positions, velocities, prediction, energy, residual, reaction and contact set must be equal exactly.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.contact.collision import Contacts
from tissue_sim_ros.core.physics.energy import NO_ATTACH, EnergyTerms, energy_model
from tissue_sim_ros.core.physics.solvers import ConstraintSolver, MaterialXPBDSolver, QuasiNewtonSolver
from tissue_sim_ros.core.physics.step_kernels import finish_step
from tissue_sim_ros.core.sim.simulation import Simulation
from tissue_sim_ros.core.timing.trajectories import experiment_a

import naive

#: experiment a's poses from here (just before the paper contact's first touch at step 158, the projection
#: contact's at 204) to STOP, then back out the same way
START, STOP = 150, 280
MATERIAL = {"material": "neo_hookean", "contact_model": "projection", "young_modulus": 2e4, "thickness": 0.01,
            "density": 1000.0}

VARIANTS = {
    "paper default (pbd gs, paper contact)": ({}, {}),
    "pbd gs projection": ({"contact_model": "projection"}, {}),
    "pbd gs projection particles": ({"contact_model": "projection", "contact_surface": "particles"}, {}),
    "pbd gs abs area": ({"area_mode": "abs"}, {}),
    "pbd jacobi all": ({"scheme": "jacobi", "jacobi_averaging": "all"}, {}),
    "pbd jacobi violated": ({"scheme": "jacobi"}, {}),
    "xpbd gs": ({"method": "xpbd"}, {}),
    "xpbd gs projection substeps 3": ({"method": "xpbd", "contact_model": "projection", "substeps": 3}, {}),
    "xpbd jacobi": ({"method": "xpbd", "scheme": "jacobi"}, {}),
    "xpbd jacobi projection substeps 2": ({"method": "xpbd", "scheme": "jacobi", "contact_model": "projection",
                                           "substeps": 2}, {}),
    "xpbd damping linear": ({"method": "xpbd", "damping": 5.0}, {}),
    "pbd damping exponential substeps 2": ({"damping": 8.0, "damping_mode": "exponential", "substeps": 2}, {}),
    "xpbd walls": ({"method": "xpbd", "wall_y_bottom": 0.05, "wall_y_top": 0.55, "contact_model": "projection"}, {}),
    "xpbd sleeping": ({"method": "xpbd", "sleep_speed": 1e-3}, {}),
    "xpbd gs parallel partition": ({"method": "xpbd", "contact_model": "projection"}, {"parallel": True}),
    "material xpbd gs": ({**MATERIAL, "method": "xpbd"}, {}),
    "material xpbd jacobi": ({**MATERIAL, "method": "xpbd", "scheme": "jacobi"}, {}),
    "material quasi_newton": (MATERIAL, {}),
    "material quasi_newton walls": ({**MATERIAL, "wall_y_bottom": 0.05}, {}),
}


def _run(values: dict, options: dict, reference: bool, monkeypatch) -> list[tuple]:
    from functools import partial

    from tissue_sim_ros.core.physics.solvers import Solver

    with monkeypatch.context() as m:
        if reference:
            for cls in (ConstraintSolver, MaterialXPBDSolver, QuasiNewtonSolver):
                m.setattr(cls, "step", naive.solver_step_reference)
        sim = Simulation.from_config(resolve_config({"iterations": 10, **values}),
                                     solver=partial(Solver, **options) if options else None)
        traj = experiment_a(sim.tool, sim.params.dt)
        poses = [p for p, _ in traj.steps(sim.params.dt)]
        poses = poses[START:STOP] + poses[START:STOP][::-1]  # in and back out
        out = []
        for pose in poses:
            r = sim.step(pose)
            out.append((sim.state.particle_q.copy(), sim.state.particle_qd.copy(), r.x_pred, r.energy.total.copy(),
                        r.residual, r.reaction_force.copy(), r.reaction_torque, r.contact_particles,
                        r.n_inverted, r.diverged, r.in_contact.copy(), r.solve_iterations, r.solve_residual))
        return out


@pytest.mark.parametrize("name", list(VARIANTS))
def test_compiled_step_is_the_reference_bit_for_bit(name, monkeypatch):
    values, options = VARIANTS[name]
    compiled = _run(values, options, False, monkeypatch)
    ref = _run(values, options, True, monkeypatch)
    assert any(len(r[7]) for r in ref), "the tool never touched: the variant tests nothing"
    for k, (a, b) in enumerate(zip(compiled, ref)):
        for i, (u, w) in enumerate(zip(a, b)):
            assert np.array_equal(u, w, equal_nan=True), f"{name}: step {k + 1}, item {i} differs"


@pytest.mark.parametrize("values", [{}, {"method": "xpbd", "area_mode": "abs"}, MATERIAL])
def test_finish_step_is_numpy_finite_check_energy_and_inversions(values):
    # finish_step: every energy term (with a grasp's springs), the finite check and inverted triangles
    sim = Simulation.from_config(resolve_config(values))
    model = sim.model
    rng = np.random.default_rng(3)
    x = model.particle_q0 + rng.normal(0, 2e-3, model.particle_q0.shape)
    v = rng.normal(0, 0.1, x.shape)
    x_pred = x + rng.normal(0, 1e-3, x.shape)
    dt = sim.params.dt
    for held in (np.zeros(0, dtype=np.int64), np.array([1, 5, 9], dtype=np.int64)):
        contacts = Contacts.empty(model.n_bodies)
        contacts.attach_idx = held
        contacts.attach_target = x[held] + 1e-3
        contacts.attach_compliance = 1e-4
        attach = (held, contacts.attach_target, 1e-4) if held.size else NO_ATTACH
        energy = EnergyTerms.zeros(model.n_bodies)
        finite, inverted = finish_step(x, v, x_pred, energy_model(model), dt, attach, energy.arrays)
        want_finite, want_inverted, want = naive.finish_reference(model, x, v, x_pred, contacts, dt)
        assert finite == want_finite and inverted == want_inverted
        np.testing.assert_allclose(np.array(energy.arrays), want, rtol=1e-9, atol=1e-18)
    v[3, 1] = np.nan
    assert finish_step(x, v, x_pred, energy_model(model), dt, NO_ATTACH, EnergyTerms.zeros(model.n_bodies).arrays)[0] \
        is False
