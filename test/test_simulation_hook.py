"""The Simulation's hook for benchmarks and batches: a step's detail, solving it again, placing the tool, another
solver; and the front door's method options. Each is compared with the direct calls it replaces, bit for bit."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from tissue_sim_ros.bench.reference import ReferenceSolver, constraint_residual, reference_step
from tissue_sim_ros.core.config import load_params_file, method_options, resolve_config
from tissue_sim_ros.core.contact.collision import ContactModel
from tissue_sim_ros.core.contact.tool import ToolPose, twist_from_poses
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics import kernels
from tissue_sim_ros.core.physics.model import Model
from tissue_sim_ros.core.physics.solvers import Solver
from tissue_sim_ros.core.physics.solvers.sleeping import SleepingSolver
from tissue_sim_ros.core.sim.simulation import Simulation, StepDetail

STRIP = mesh_rectangle(0.4, 0.2, 0.05)
#: A box pushing down into the strip's top surface from 2 cm above it, 4 mm per step.
POSES = [ToolPose(0.2, 0.2 + 0.0025 + 0.02 - 0.004 * k, 0.0) for k in range(12)]


def _config(contact_model: str, **values):
    return resolve_config({"contact_model": contact_model, "boundary_y_bottom": 0.01, "boundary_y_top": math.nan,
                           "tool_shape": "box", "tool_length": 0.2, "tool_width": 0.005, **values})


def _direct(cfg, solver_factory=Solver):
    """The path the benchmarks took before: their own Model, ContactModel and Solver."""
    model = Model.from_mesh(STRIP, cfg.sim)
    return model, ContactModel(model, cfg.tool), solver_factory(model)


def _same_state(a, b) -> bool:
    return np.array_equal(a.particle_q, b.particle_q) and np.array_equal(a.particle_qd, b.particle_qd)


@pytest.mark.parametrize("contact_model, method", [("paper", "pbd"), ("projection", "xpbd"),
                                                   ("projection", "xpbd_substep"), ("paper", "xpbd_jacobi")])
def test_step_detail_is_what_the_direct_solver_calls_saw_and_gave(contact_model: str, method: str) -> None:
    cfg = _config(contact_model, method=method)
    sim = Simulation.from_config(cfg, mesh=STRIP)
    sim.place_tool(POSES[0])
    model, contact, solver = _direct(cfg)
    state, out = model.state(), model.state()
    dt = model.params.dt
    touched = 0
    for k in range(1, len(POSES)):
        start = sim.state.copy()
        report = sim.step(POSES[k], detail=True)
        contacts = contact.detect(state, POSES[k - 1], POSES[k], twist_from_poses(POSES[k - 1], POSES[k], dt), dt)
        info = solver.step(state, out, contacts, dt)
        d = report.detail
        assert isinstance(d, StepDetail) and (d.tool_pose0, d.tool_pose1, d.dt) == (POSES[k - 1], POSES[k], dt)
        assert _same_state(d.state_in, start) and _same_state(d.state_in, state)
        for name in ("held_idx", "held_dx", "candidates", "surface_edges", "tool_shape0", "tool_shape1", "touched",
                     "d_star"):
            assert np.array_equal(getattr(d.contacts, name), getattr(contacts, name)), name
        assert np.array_equal(d.info.x_pred, info.x_pred) and np.array_equal(report.x_pred, info.x_pred)
        assert d.info.residual == info.residual == report.residual
        assert (d.info.contact_dx is None) == (info.contact_dx is None)
        if info.contact_dx is not None:
            assert np.array_equal(d.info.contact_dx, info.contact_dx) and d.info.contact_dx is not info.contact_dx
        assert _same_state(sim.state, out)
        touched += report.n_contact_particles
        state, out = out, state
    assert touched > 0  # the tool reached the tissue


def test_detail_changes_nothing_and_is_off_by_default() -> None:
    cfg = _config("projection", method="xpbd")
    a, b = Simulation.from_config(cfg, mesh=STRIP), Simulation.from_config(cfg, mesh=STRIP)
    for s in (a, b):
        s.place_tool(POSES[0])
    for pose in POSES[1:]:
        ra, rb = a.step(pose), b.step(pose, detail=True)
        assert ra.detail is None and rb.detail is not None
        assert ra.energy.scene_total == rb.energy.scene_total and _same_state(a.state, b.state)


@pytest.mark.parametrize("contact_model", ["paper", "projection"])
def test_solve_equals_a_fresh_solver_on_the_same_step(contact_model: str) -> None:
    cfg = _config(contact_model, method="xpbd", iterations=5)
    sim = Simulation.from_config(cfg, mesh=STRIP)
    sim.place_tool(POSES[0])
    for pose in POSES[1:6]:
        report = sim.step(pose, detail=True)
    d = report.detail
    after = sim.state.copy()
    # no changes: the step's own result, bit for bit
    again, info = sim.solve(d)
    assert _same_state(again, after) and info.residual == report.residual
    # other iteration counts: as a Solver of the model with those parameters, from the same state and contacts
    for n in (1, 16):
        state, info = sim.solve(d, iterations=n)
        model = sim.model.with_params(sim.params.with_(iterations=n))
        out = model.state()
        want = Solver(model).step(d.state_in.copy(), out, d.contacts, d.dt)
        assert _same_state(state, out) and info.residual == want.residual
    # the simulation and the kept detail are untouched
    assert _same_state(sim.state, after) and sim.step_count == 5 and sim.params.iterations == 5
    assert _same_state(d.state_in, report.detail.state_in)
    # another solver: the exact reference on the same step
    state, info = sim.solve(d, solver=functools.partial(ReferenceSolver, max_iterations=50))
    ref = reference_step(sim.model, d.state_in, d.contacts, d.dt, max_iterations=50)
    assert np.array_equal(state.particle_q, ref.particle_q) and np.array_equal(state.particle_qd, ref.particle_qd)
    assert np.array_equal(info.result.particle_q, ref.particle_q) and info.result.energy == ref.energy


def test_reference_solver_steps_the_exact_run_of_a_simulation() -> None:
    cfg = _config("paper", method="xpbd")
    sim = Simulation.from_config(cfg, mesh=STRIP, solver=functools.partial(ReferenceSolver, max_iterations=60))
    sim.report_tool_checks = False
    sim.place_tool(POSES[0])
    model, contact, _ = _direct(cfg)
    state = model.state()
    dt = model.params.dt
    for k in range(1, 6):
        report = sim.step(POSES[k])
        contacts = contact.detect(state, POSES[k - 1], POSES[k], twist_from_poses(POSES[k - 1], POSES[k], dt), dt)
        ref = reference_step(model, state, contacts, dt, max_iterations=60)
        state = type(state)(ref.particle_q, ref.particle_qd)
        assert _same_state(sim.state, state) and not report.diverged
        assert np.array_equal(report.x_pred, ref.x_pred)
        assert math.isclose(report.residual, kernels.constraint_residual(
            ref.particle_q, model.edge_indices, model.edge_rest_length, model.tri_indices, model.tri_rest_area, True),
            rel_tol=1e-9, abs_tol=1e-15)
    assert constraint_residual(model, model.particle_q0) == 0.0


def test_place_tool_is_where_the_next_step_sweeps_from() -> None:
    cfg = _config("projection", method="xpbd")
    placed, assigned = Simulation.from_config(cfg, mesh=STRIP), Simulation.from_config(cfg, mesh=STRIP)
    placed.place_tool(POSES[3])
    assigned.tool_pose = POSES[3]  # what batch.py and the benchmarks did
    assert placed.tool_pose == POSES[3] and placed.step_count == 0 and _same_state(placed.state, assigned.state)
    for pose in POSES[4:]:
        rp, ra = placed.step(pose, detail=True), assigned.step(pose)
        assert rp.energy.scene_total == ra.energy.scene_total and _same_state(placed.state, assigned.state)
    assert rp.detail.tool_pose0 == POSES[-2]
    placed.place_tool(None)
    assert placed.tool_pose is None


def test_use_solver_equals_swapping_the_solver_and_survives_retune() -> None:
    cfg = _config("paper", method="xpbd", sleep_speed=0.0)
    sim, swapped = Simulation.from_config(cfg, mesh=STRIP), Simulation.from_config(cfg, mesh=STRIP)
    factory = functools.partial(SleepingSolver, wake_radius=0.05, sleep_speed=1e-2, quiet_steps=2)
    sim.use_solver(factory)
    swapped.solver = factory(swapped.model)  # the old way
    assert isinstance(sim.solver, SleepingSolver)
    for s in (sim, swapped):
        s.place_tool(POSES[0])
    for pose in POSES[1:]:
        sim.step(pose)
        swapped.step(pose)
        assert _same_state(sim.state, swapped.state)
    sim.retune(sim.config.replace(iterations=7))
    assert isinstance(sim.solver, SleepingSolver) and sim.solver.model.params.iterations == 7
    sim.use_solver(functools.partial(Solver, order="stored"))
    sim.retune(sim.config.replace(iterations=9))
    assert sim.solver.order == "stored" and sim.solver.params.iterations == 9


def test_method_options_are_the_alias_table_with_an_explicit_count() -> None:
    assert method_options("xpbd_substep") == {"method": "xpbd", "scheme": "gauss_seidel", "substeps": 30,
                                              "iterations": 1}
    assert method_options("xpbd_substep", 1) == {"method": "xpbd", "scheme": "gauss_seidel", "substeps": 1,
                                                 "iterations": 1}
    assert method_options("pbd_jacobi", 7) == {"method": "pbd", "scheme": "jacobi", "iterations": 7, "substeps": 1}
    assert method_options("xpbd") == {"method": "xpbd", "scheme": "gauss_seidel"}
    # as explicit overrides they win over a parameter file's values: one substep stays one (the alias alone,
    # seeing the shipped value 1, would make it 30)
    assert resolve_config(method_options("xpbd_substep", 1)).sim.substeps == 1
    assert resolve_config({"method": "xpbd_substep", "substeps": 1}).sim.substeps == 30
    for bad in ("newton", "jacobi"):
        with pytest.raises(InputError, match="expected one of"):
            method_options(bad)
    with pytest.raises(InputError, match="count"):
        method_options("xpbd", 0)


def test_accuracy_settings_are_the_methods_they_were() -> None:
    from tissue_sim_ros.bench.accuracy import Setting, strip_scene

    scene = strip_scene(spacing=0.1, n_steps=1)
    # what Setting.params did: base.with_(method, scheme, iterations, substeps), nothing else changed
    expected = {"pbd": ("pbd", "gauss_seidel", 4, 1), "pbd_jacobi": ("pbd", "jacobi", 4, 1),
                "xpbd": ("xpbd", "gauss_seidel", 4, 1), "xpbd_jacobi": ("xpbd", "jacobi", 4, 1),
                "xpbd_substep": ("xpbd", "gauss_seidel", 1, 4), "newton": ("xpbd", "gauss_seidel", 4, 1)}
    for method, want in expected.items():
        got = Setting(method, 4).config(scene.config)
        assert (got.sim.method, got.sim.scheme, got.sim.iterations, got.sim.substeps) == want
        assert set(scene.config.changed(got)) <= {"method", "scheme", "iterations", "substeps"}
    assert scene.params.boundary_y_bottom == 0.05 and math.isnan(scene.params.boundary_y_top)


def test_partial_parameter_file_holds_only_the_names_asked(tmp_path) -> None:
    values = {"material": "neo_hookean", "spacing": 0.004, "tool_shape": "sphere", "boundary_y_top": 1.0}
    cfg = resolve_config(values)
    path = tmp_path / "scene.yaml"
    path.write_text(cfg.to_yaml(names=values))
    assert load_params_file(path) == values
    assert resolve_config(params_file=path).changed(cfg) == []
    with pytest.raises(InputError, match="unknown"):
        cfg.to_yaml(names=["spacing", "spaceing"])
    full = tmp_path / "all.yaml"
    full.write_text(cfg.to_yaml(node_name="/**"))
    assert resolve_config(params_file=full).changed(cfg) == []
