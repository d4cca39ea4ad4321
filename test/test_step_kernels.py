"""One compiled call per step (core/physics/step_kernels.py) against the Python loop around the kernels, bit for bit.

``Solver.step`` runs :func:`~tissue_sim_ros.core.physics.step_kernels.solve_step` for the constraint methods and
``Simulation.step`` :func:`~tissue_sim_ros.core.physics.step_kernels.finish_step`; ``Solver.step_reference`` and
``Simulation.step_reference`` are the loops they replace. Each variant runs the same tool trajectory (experiment a's
insertion, into the tissue and out) twice, once with ``Solver.step`` swapped for ``step_reference``, and every step's
positions, velocities, prediction, energy, residual, reaction and contact set must be equal exactly.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.physics.solvers import Solver
from tissue_sim_ros.core.sim.simulation import Simulation
from tissue_sim_ros.core.timing.trajectories import experiment_a

#: experiment a's poses from here (just before the paper contact's first touch at step 158, the projection
#: contact's at 204) to STOP, then back out the same way
START, STOP = 150, 280

VARIANTS = {
    "paper default (pbd gs, paper contact)": {},
    "pbd gs projection": {"contact_model": "projection"},
    "pbd gs projection particles": {"contact_model": "projection", "contact_surface": "particles"},
    "pbd gs abs area": {"area_mode": "abs"},
    "pbd jacobi all": {"scheme": "jacobi", "jacobi_averaging": "all"},
    "xpbd gs": {"method": "xpbd"},
    "xpbd gs projection substeps 3": {"method": "xpbd", "contact_model": "projection", "substeps": 3},
    "xpbd jacobi": {"method": "xpbd", "scheme": "jacobi"},
    "xpbd jacobi projection substeps 2": {"method": "xpbd", "scheme": "jacobi", "contact_model": "projection",
                                          "substeps": 2},
    "xpbd damping linear": {"method": "xpbd", "damping": 5.0},
    "pbd damping exponential substeps 2": {"damping": 8.0, "damping_mode": "exponential", "substeps": 2},
    "xpbd walls": {"method": "xpbd", "wall_y_bottom": 0.05, "wall_y_top": 0.55, "contact_model": "projection"},
    "xpbd sleeping": {"method": "xpbd", "sleep_speed": 1e-3},
    "pbd jacobi violated (reference path)": {"scheme": "jacobi"},
    "material neo_hookean (reference solver path, compiled finish)": {"material": "neo_hookean", "method": "xpbd",
                                                                      "contact_model": "projection"},
}


def _run(values: dict, reference: bool, monkeypatch) -> list[tuple]:
    with monkeypatch.context() as m:
        if reference:
            m.setattr(Solver, "step", Solver.step_reference)
        sim = Simulation.from_config(resolve_config({"iterations": 10, **values}))
        traj = experiment_a(sim.tool, sim.params.dt)
        poses = [p for p, _ in traj.steps(sim.params.dt)]
        poses = poses[START:STOP] + poses[START:STOP][::-1]  # in and back out
        out = []
        for pose in poses:
            r = sim.step_reference(pose) if reference else sim.step(pose)
            out.append((sim.state.particle_q.copy(), sim.state.particle_qd.copy(), r.x_pred, r.energy.total.copy(),
                        r.residual, r.reaction_force.copy(), r.reaction_torque, r.contact_particles,
                        r.n_inverted, r.diverged, r.in_contact.copy()))
        return out


@pytest.mark.parametrize("name", list(VARIANTS))
def test_compiled_step_is_the_reference_bit_for_bit(name, monkeypatch):
    values = VARIANTS[name]
    compiled = _run(values, False, monkeypatch)
    ref = _run(values, True, monkeypatch)
    assert any(len(r[7]) for r in ref), "the tool never touched: the variant tests nothing"
    for k, (a, b) in enumerate(zip(compiled, ref)):
        for i, (u, w) in enumerate(zip(a, b)):
            assert np.array_equal(u, w), f"{name}: step {k + 1}, item {i} differs"


def test_the_compiled_path_is_taken():
    for values, compiled in (({}, True), ({"scheme": "jacobi", "jacobi_averaging": "all"}, True),
                             ({"scheme": "jacobi"}, False)):
        sim = Simulation.from_config(resolve_config(values))
        assert sim.solver.compiled is compiled
