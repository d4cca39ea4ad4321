"""The barrier step stiffens its barrier where a load squeezes a pair deep inside dhat (IPC's adaptive stiffness).

The case: a 1 MPa strip with slivers, the 5 mm capsule jumping a third of the strip deep in one 20 ms step and
then held (``bench stability --material``'s hardest press). With the barrier's stiffness fixed at E x thickness
the held steps stopped short of their tolerance, a pair's gap fell tenfold per step and the reaction read up to
1e8 N. The load is what the reaction must read: at rest it balances the strip's elastic push, the same whatever
the stiffness (a stiffer barrier only moves the contact's gap toward dhat).
"""
from __future__ import annotations

import math

import numpy as np

from tissue_sim_ros.bench import material_stability as ms
from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.physics.solvers import ipc as ipc_solver
from tissue_sim_ros.core.sim.simulation import Simulation


def _hard_press() -> tuple[Simulation, list]:
    cfg = resolve_config({"material": "neo_hookean", "young_modulus": 1e6, "poisson_ratio": 0.45,
                          "thickness": 0.005, "density": 1000.0, "dt": 0.02, "boundary_y_bottom": 1e-9,
                          "boundary_y_top": math.nan, "tool_shape": "capsule", "tool_length": ms.TOOL.length,
                          "tool_radius": ms.TOOL.radius, "sleep_speed": 0.0})
    assert cfg.sim.method == "ipc" and cfg.sim.contact_model == "barrier"  # the material's default
    sim = Simulation.from_config(cfg, mesh=ms.make_mesh("slivers"))
    poses = ms.poses(0.02, 1.0, "press")
    sim.place_tool(poses[0])
    return sim, poses


def test_a_hard_press_stiffens_the_barrier_and_holds_the_load():
    sim, poses = _hard_press()
    solver = sim.solver
    kappa0 = solver.kappa
    reports = [sim.step(p) for p in poses[1:]]
    assert all(r.solve_converged for r in reports), [r.solve_residual for r in reports]
    assert solver.kappa > kappa0 and solver.kappa <= ipc_solver.KAPPA_MAX * kappa0
    held = np.array([r.reaction_force[:2] for r in reports[-ms.HOLD_STEPS:]])
    # steady under the held tool, and the load's size: the strip pressed 6.7 mm into 20 mm of 1 MPa x 5 mm
    # pushes back with about E t x (strain ~ 1/3) x (contact width ~ 1.5 cm) = 25 N
    assert np.all(np.abs(held[:, 1] - held[-1, 1]) < 1e-3 * abs(held[-1, 1]))
    assert 10.0 < held[-1, 1] < 50.0
    # every pair ends outside KAPPA_RAISE_GAP dhat, nothing inverted, nothing inside the tool
    gaps = solver._report[:, [1, 5]].min()
    assert gaps >= ipc_solver.KAPPA_RAISE_GAP * solver.dhat
    assert all(r.n_inverted == 0 for r in reports)


def test_the_stiffness_is_carried_in_snapshots_and_reset():
    sim, poses = _hard_press()
    kappa0 = sim.solver.kappa
    for p in poses[1:4]:
        sim.step(p)
    snap = sim.snapshot()
    raised = sim.solver.kappa
    assert raised > kappa0
    after = [sim.step(p).reaction_force for p in poses[4:7]]
    q_after = sim.state.particle_q.copy()
    # a new Simulation restored from the snapshot steps as the live one did, bit for bit
    other, _ = _hard_press()
    other.restore(snap)
    assert other.solver.kappa == raised
    again = [other.step(p).reaction_force for p in poses[4:7]]
    assert all(np.array_equal(a, b) for a, b in zip(after, again))
    assert np.array_equal(other.state.particle_q, q_after)
    # reset: the stiffness as built, and the run from the start is the first run's
    sim.reset()
    assert sim.solver.kappa == kappa0
    fresh, _ = _hard_press()
    sim.place_tool(poses[0])
    for p in poses[1:4]:
        a, b = sim.step(p), fresh.step(p)
        assert np.array_equal(a.reaction_force, b.reaction_force)
    assert np.array_equal(sim.state.particle_q, fresh.state.particle_q)
