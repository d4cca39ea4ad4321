"""The grasper (issue 30): its shape, the attachment kernel against its NumPy twin, the jaw's hysteresis, what it
grasps and releases, the pull on the tool and the attachment energy, checked against the equations."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.contact.kernels import points_sdf
from tissue_sim_ros.core.contact.tool import ToolPose, ToolShape, tool_shape_array
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.attach import project_attachments
from tissue_sim_ros.core.sim.simulation import Simulation

import naive

GRASPER = {"tool_shape": "grasper", "tool_length": 0.05, "shaft_width": 0.004, "jaw_length": 0.01,
           "method": "xpbd", "contact_model": "projection", "contact_margin": 0.001, "gravity": 0.0,
           "pin_y_bottom": 0.001, "grasp_radius": 0.006, "boundary_y_top": float("nan"),
           "boundary_y_bottom": float("nan")}
TOP = 0.02  # the strip's top surface [m]
REST_TIP = TOP + 0.001  # the tip resting on it (the contact margin)


def strip_sim(**changes) -> Simulation:
    """A 6 cm x 2 cm strip (16 x 6 particles), pinned at the bottom, the grasper above its middle."""
    cfg = resolve_config({**GRASPER, **changes})
    return Simulation.from_config(cfg, mesh=mesh_rectangle(0.06, 0.02, 0.004, origin=(-0.03, 0.0)))


def settle_tip(sim: Simulation, jaw: float = 1.0) -> None:
    sim.step(ToolPose(0.0, REST_TIP + 0.002, 0.0), jaw=jaw)
    for _ in range(3):
        sim.step(ToolPose(0.0, REST_TIP, 0.0))


def test_grasper_shape_pose_is_the_tip_and_the_shaft_points_up():
    shape = ToolShape("grasper", length=0.05, shaft_width=0.004, jaw_length=0.01)
    packed = tool_shape_array(shape, ToolPose(0.1, 0.2, 0.0))
    np.testing.assert_allclose(packed[:4], [0.1, 0.2 + 0.025, 0.0, 1.0], atol=1e-15)
    # the tip (the pose) is on the surface, a point above it inside, one below it outside
    pts = np.array([[0.1, 0.2], [0.1, 0.23], [0.1, 0.19], [0.1, 0.2 + 0.051]])
    sdf, grad = np.empty(4), np.empty((4, 2))
    points_sdf(pts, packed, sdf, grad)
    assert abs(sdf[0]) < 1e-12 and sdf[1] < 0 and sdf[2] == pytest.approx(0.01) and sdf[3] > 0
    # yawed a quarter turn the shaft points -x from the tip
    packed = tool_shape_array(shape, ToolPose(0.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(packed[:2], [-0.025, 0.0], atol=1e-15)
    with pytest.raises(InputError, match="shaft_width"):
        ToolShape("grasper", length=0.05, shaft_width=0.0)
    with pytest.raises(InputError, match="tool_length"):
        ToolShape("grasper", length=0.005, shaft_width=0.004, jaw_length=0.01)
    assert shape.outline(0.5).shape[1] == 2


def test_attachment_kernel_equals_its_numpy_twin():
    rng = np.random.default_rng(3)
    n, k = 40, 12
    x = rng.normal(size=(n, 2))
    inv_mass = rng.uniform(0.5, 2.0, n)
    inv_mass[[2, 7]] = 0.0  # held by something else: not moved
    idx = rng.choice(n, k, replace=False).astype(np.int64)
    idx[:2] = [2, 7]
    target = rng.normal(size=(k, 2))
    lam0 = rng.normal(size=(k, 2)) * 1e-3
    for alpha in (0.0, 1e-3, 10.0):
        got_x, got_lam = x.copy(), lam0.copy()
        project_attachments(got_x, inv_mass, idx, target, alpha, got_lam)
        want_x, want_lam = naive.project_attachments(x, inv_mass, idx, target, alpha, lam0)
        np.testing.assert_allclose(got_x, want_x, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(got_lam, want_lam, rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(got_x[[2, 7]], x[[2, 7]])
    # alpha 0: a free particle lands on its target
    got_x = x.copy()
    project_attachments(got_x, inv_mass, idx, target, 0.0, np.zeros((k, 2)))
    np.testing.assert_allclose(got_x[idx[2:]], target[2:], atol=1e-14)


def test_hanging_particles_stretch_their_springs_by_m_g_c():
    """Independent reference: at rest a held particle of mass m under gravity g hangs below its target by
    x - t = m g c (force balance (t - x) / c + m g = 0), and pulls the tool with sum m g (down)."""
    c = 0.5
    sim = strip_sim(gravity=-9.8, stiffness_spring=0.0, stiffness_area=0.0, pin_y_bottom=float("nan"),
                    grasp_radius=0.5, grasp_compliance=c, damping=20.0, contact_model="none")
    sim.step(ToolPose(0.0, 0.05, 0.0), jaw=0.0)
    n = sim.model.n_particles
    report = None
    for _ in range(400):
        report = sim.step(ToolPose(0.0, 0.05, 0.0))
    assert report.grasped.size == n
    m = sim.model.particle_mass
    target = sim.grasp.targets(ToolPose(0.0, 0.05, 0.0))
    sag = sim.state.particle_q[sim.grasp.idx] - target
    np.testing.assert_allclose(sag[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(sag[:, 1], -m[sim.grasp.idx] * 9.8 * c, rtol=1e-4)
    np.testing.assert_allclose(report.reaction_force, [0.0, -m.sum() * 9.8], rtol=1e-4, atol=1e-9)
    # the attachment term: dt^2 sum |x - t|^2 / (2 c)
    want = sim.params.dt ** 2 * 0.5 * (sag * sag).sum() / c
    assert report.energy.attach.sum() == pytest.approx(want, rel=1e-9)
    assert report.energy.scene_total == pytest.approx(report.energy.total.sum())


def test_hysteresis_air_and_closed_jaw():
    sim = strip_sim()
    # in air: closing grasps nothing
    sim.step(ToolPose(0.0, 0.05, 0.0), jaw=0.0)
    assert sim.grasp.closed and sim.grasp.n_held == 0
    # a closed jaw brought onto the surface does not grasp: it must open and close again
    settle_tip(sim, jaw=0.0)
    assert sim.grasp.n_held == 0
    sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.3)  # between the angles: still closed
    assert sim.grasp.closed and sim.grasp.n_held == 0
    sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.5)  # opens
    assert not sim.grasp.closed
    sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.3)  # between: still open
    assert not sim.grasp.closed and sim.grasp.n_held == 0
    r = sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.1)  # closes on the surface: grasps
    held = r.grasped.copy()
    assert held.size > 0
    assert np.all(np.hypot(*(sim.model.particle_q0[held] - [0.0, TOP]).T) < 0.006 + 1e-9)
    r = sim.step(ToolPose(0.0, REST_TIP + 0.001, 0.0), jaw=0.35)  # between: still holding
    np.testing.assert_array_equal(r.grasped, held)
    r = sim.step(ToolPose(0.0, REST_TIP + 0.002, 0.0), jaw=0.45)  # opens: released
    assert r.grasped.size == 0 and sim.grasp.n_held == 0
    with pytest.raises(InputError, match="jaw=nan"):
        sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=float("nan"))


@pytest.mark.parametrize("material", ["constraints", "neo_hookean"])
def test_lift_follows_the_tool_pulls_it_back_and_release_lets_go(material):
    sim = strip_sim(material=material)
    settle_tip(sim)
    i = int(np.argmin(np.hypot(*(sim.state.particle_q - [0.0, TOP]).T)))
    y0 = sim.state.particle_q[i, 1]
    e0 = sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.0).energy.scene_total
    rise = 0.0
    for k in range(10):  # lift 1 cm at 1 mm per step
        rise = 0.001 * (k + 1)
        r = sim.step(ToolPose(0.0, REST_TIP + rise, 0.0))
    assert i in r.grasped
    assert abs((sim.state.particle_q[i, 1] - y0) - rise) < 0.002
    assert r.reaction_force[1] < 0 and r.attach_force[1] < 0  # the tissue pulls the tool back down
    assert r.energy.scene_total > e0 and r.energy.attach.sum() > 0
    assert np.isfinite(r.reaction_force).all() and not r.diverged
    for _ in range(40):
        r = sim.step(ToolPose(0.0, REST_TIP + rise, 0.0), jaw=1.0)
    assert r.grasped.size == 0 and r.energy.attach.sum() == 0.0
    assert sim.state.particle_q[i, 1] - y0 < 0.001  # the strip springs back


def test_compiled_step_equals_reference_and_snapshots_carry_the_grasp():
    from functools import partial

    a, b = strip_sim(), strip_sim()
    b.solver.step = partial(naive.solver_step_reference, b.solver)  # the Python loop (test/naive.py)
    poses = [(ToolPose(0.0, REST_TIP + 0.002, 0.0), 1.0), (ToolPose(0.0, REST_TIP, 0.0), None),
             (ToolPose(0.0, REST_TIP, 0.0), 0.0)] + [(ToolPose(0.001 * k, REST_TIP + 0.001 * k, 0.1 * k), None)
                                                    for k in range(1, 6)]
    for pose, jaw in poses:
        ra = a.step(pose, jaw=jaw)
        rb = b.step(pose, jaw=jaw)
        np.testing.assert_array_equal(a.state.particle_q, b.state.particle_q)
        np.testing.assert_array_equal(ra.reaction_force, rb.reaction_force)
    assert ra.grasped.size > 0
    snap = a.snapshot()
    c = strip_sim()
    c.restore(snap)
    for k in range(3):
        pose = ToolPose(0.0, REST_TIP + 0.01 + 0.001 * k, 0.5)
        ra, rc = a.step(pose), c.step(pose)
        np.testing.assert_array_equal(a.state.particle_q, c.state.particle_q)
        np.testing.assert_array_equal(ra.grasped, rc.grasped)
    a.reset()
    assert a.grasp.n_held == 0 and a.grasp.jaw is None


def test_trajectory_files_carry_the_jaw_and_rollouts_take_it(tmp_path):
    from tissue_sim_ros.core.contact.tool import WaypointTrajectory
    from tissue_sim_ros.core.sim.rollout import rollout
    from tissue_sim_ros.core.timing.trajectories import load_trajectory, write_trajectory_csv

    dt = 0.01
    traj = WaypointTrajectory([0.0, 0.03, 0.05, 0.15], [(0.0, REST_TIP + 0.003, 0.0), (0.0, REST_TIP, 0.0),
                                                         (0.0, REST_TIP, 0.0), (0.0, REST_TIP + 0.01, 0.0)],
                              jaws=[1.0, 1.0, 0.0, 0.0])
    assert traj.jaw_at(0.04) == pytest.approx(0.5)
    path = write_trajectory_csv(tmp_path / "grasp.csv", traj, dt)
    assert path.read_text().splitlines()[0] == "time,x,y,yaw,jaw"
    back = load_trajectory(path, dt)
    assert [j for *_, j in back.steps_with_jaw(dt)] == [j for *_, j in traj.steps_with_jaw(dt)]
    yaml_file = tmp_path / "grasp.yaml"
    yaml_file.write_text("waypoints:\n  - {time: 0.0, x: 0.0, y: 0.1, yaw: 0.0, jaw: 1.0}\n"
                         "  - {time: 0.1, x: 0.0, y: 0.1, yaw: 0.0, jaw: 0.0}\n")
    assert load_trajectory(yaml_file, dt).jaw_at(0.05) == pytest.approx(0.5)
    yaml_file.write_text("waypoints:\n  - {time: 0.0, x: 0.0, y: 0.1, yaw: 0.0, jaw: 1.0}\n"
                         "  - {time: 0.1, x: 0.0, y: 0.1, yaw: 0.0}\n")
    with pytest.raises(InputError, match="jaw"):
        load_trajectory(yaml_file, dt)
    # a rollout of the file equals stepping by hand, and keeps the jaw, the held count and the attachment term
    a, b = strip_sim(), strip_sim()
    run = rollout(a, back.steps_with_jaw(dt))
    for pose, twist, jaw in traj.steps_with_jaw(dt):
        b.step(pose, twist, jaw=jaw)
    np.testing.assert_array_equal(a.state.particle_q, b.state.particle_q)
    assert run.n_grasped[-1] > 0 and run.n_grasped[0] == 0 and run.attach[-1].sum() > 0
    names, table = run.energy_table()
    assert "jaw" in names and "grasped" in names and "body0_attach" in names
    np.testing.assert_allclose(run.scene_total, table[:, names.index("energy_total")])


def test_batches_carry_the_jaw_serial_equals_pool_equals_stepping():
    from tissue_sim_ros.core.contact.tool import WaypointTrajectory
    from tissue_sim_ros.core.sim.batch import BatchScene, RolloutPool, ToolPath, rollout_batch

    dt = 0.01
    sim = strip_sim()
    settle_tip(sim)
    snap = sim.snapshot()
    lift = WaypointTrajectory([0.0, 0.02, 0.08], [(0.0, REST_TIP, 0.0), (0.0, REST_TIP, 0.0),
                                                  (0.0, REST_TIP + 0.006, 0.0)], jaws=[1.0, 0.0, 0.0])
    path = ToolPath.from_trajectory(lift, dt)
    assert path.jaws is not None and path.jaws[-1] == 0.0
    no_jaw = ToolPath(path.poses, path.twists, path.start)
    serial = rollout_batch(snap, [path, no_jaw], scene=BatchScene.from_simulation(sim), final_state=True)
    with RolloutPool(sim, workers=1) as pool:
        pooled = rollout_batch(snap, [path, no_jaw], pool=pool, final_state=True)
    for s, p in zip(serial.candidates, pooled.candidates):
        assert np.array_equal(s.energy, p.energy)
        assert np.array_equal(s.final_state.particle_q, p.final_state.particle_q)
    # the grasping candidate is the one stepped by hand, and it differs from the one that never closes
    by_hand = strip_sim()
    by_hand.restore(snap)
    by_hand.place_tool(path.start)
    for pose, twist, jaw in lift.steps_with_jaw(dt):
        by_hand.step(pose, twist, jaw=jaw)
    np.testing.assert_array_equal(serial.candidates[0].final_state.particle_q, by_hand.state.particle_q)
    assert not np.array_equal(serial.candidates[0].energy, serial.candidates[1].energy)


def test_relocation_check_refuses_a_pose_in_the_tissue():
    sim = strip_sim()
    assert sim.tool_overlaps_tissue(ToolPose(0.0, 0.01, 0.0))  # the shaft through the strip
    assert not sim.tool_overlaps_tissue(ToolPose(0.0, REST_TIP + 0.001, 0.0))


@pytest.mark.parametrize("speed, distance", [(0.005, 0.1), (0.005, 0.3)])
def test_fast_lift_and_huge_pull_on_the_retract_scene_stay_finite(speed, distance):
    """The retract scene's grasp pulled at max_tool_jump per step (0.5 m/s) to 10 cm and 30 cm: measured, nothing
    diverges or tears (there is no tearing model); the flap inverts triangles at 30 cm, and every number the node
    would publish stays finite."""
    from tissue_sim_ros.core.resources import scene_params_file
    from tissue_sim_ros.core.sim.scene import build_simulation, load_params_file

    sim = build_simulation(load_params_file(scene_params_file("retract")))
    top = 0.016
    sim.step(ToolPose(0.04, top + 0.003, 0.0), jaw=1.0)
    for _ in range(3):
        sim.step(ToolPose(0.04, top + 0.0002, 0.0))
    r = sim.step(ToolPose(0.04, top + 0.0002, 0.0), jaw=0.0)
    assert r.grasped.size > 0
    for k in range(int(round(distance / speed))):
        r = sim.step(ToolPose(0.04, top + 0.0002 + speed * (k + 1), 0.0))
        assert not r.diverged and r.grasped.size > 0
        assert np.isfinite(sim.state.particle_q).all() and np.isfinite(r.reaction_force).all()
        assert np.isfinite(r.energy.total).all() and math.isfinite(r.reaction_torque)
    assert r.reaction_force[1] < 0


def test_step_messages_of_a_grasper_carry_the_held_count_the_term_and_the_cyan_markers():
    from tissue_sim_ros.ros import messages as M

    sim = strip_sim()
    settle_tip(sim)
    r = sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.0)
    r = sim.step(ToolPose(0.0, REST_TIP + 0.002, 0.0))
    enc = M.StepEncoder(sim.model, sim.tool)
    out = enc.encode((1, 0), "world", r, sim.state.particle_q, markers=True, tool_pose=(0.0, REST_TIP + 0.002, 0.0))
    assert M.decode_uint32(out.messages["tool/grasped"]) == r.grasped.size > 0
    assert M.decode_float64(out.messages["tissue/energy/attach"]) == r.energy.attach.sum() > 0
    assert M.decode_float64(out.messages["tissue/energy"]) == pytest.approx(r.energy.scene_total, rel=1e-15)
    markers = {m.ns: m for m in M.decode_marker_array(out.messages["tissue/markers"])}
    np.testing.assert_allclose(markers["grasped"].points[:, :2], sim.state.particle_q[r.grasped])
    # the tool marker is the grasper's envelope, from its tip (the pose) up the shaft
    tool = markers["tool"].points[:, :2]
    assert tool[:, 1].min() == pytest.approx(REST_TIP + 0.002, abs=1e-9) and tool[:, 1].max() > REST_TIP + 0.04
    # a box tool's messages are as before: no grasp topics, no grasped marker
    box = M.StepEncoder(sim.model, ToolShape())
    out = box.encode((1, 0), "world", r, sim.state.particle_q, markers=True)
    assert "tool/grasped" not in out.messages and "tissue/energy/attach" not in out.messages
    assert "grasped" not in {m.ns for m in M.decode_marker_array(out.messages["tissue/markers"])}


def test_grasp_stability_runs_read_a_grasper_in_its_own_frame():
    """bench stability --grasp: a fast lift of the retract scene's grasp is stable (the failure checks place the
    grasper's box up its shaft: read at the pose, its held particles looked tunnelled)."""
    from tissue_sim_ros.bench.grasp_stability import run_grasp

    fast = run_grasp("neo_hookean", 10, 1e-4, 0.005, 0.02, hold_steps=5)
    assert fast["outcome"] == "stable" and fast["held"] > 0 and fast["released_step"] == ""
    assert fast["diverged_steps"] == 0 and abs(fast["lag_mm"]) < 0.1 and fast["max_force_n"] > 0


def test_release_restores_free_motion_exactly():
    """After the jaw opens, the tissue moves as one that was never grasped: the same steps from the same state and
    tool pose give the same bits."""
    sim = strip_sim()
    settle_tip(sim)
    sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.0)
    for k in range(1, 6):
        sim.step(ToolPose(0.0, REST_TIP + 0.001 * k, 0.0))
    r = sim.step(ToolPose(0.0, REST_TIP + 0.006, 0.0), jaw=1.0)
    assert r.grasped.size == 0 and not sim.grasp.closed
    free = strip_sim()
    free.set_state(sim.state)
    free.place_tool(sim.tool_pose)
    for k in range(10):
        pose = ToolPose(0.001 * k, REST_TIP + 0.006 + 0.001 * k, 0.0)
        a, b = sim.step(pose), free.step(pose)
        np.testing.assert_array_equal(sim.state.particle_q, free.state.particle_q)
        np.testing.assert_array_equal(a.reaction_force, b.reaction_force)
        assert a.energy.scene_total == b.energy.scene_total


def test_contacts_carry_the_attachments_as_plain_arrays():
    """The solvers' interface: attach_idx (K,) int64, attach_target (K, 2) float64, attach_compliance [m/N] and its
    inverse attach_stiffness [N/m] on the step's Contacts."""
    sim = strip_sim()
    settle_tip(sim)
    sim.step(ToolPose(0.0, REST_TIP, 0.0), jaw=0.0)
    r = sim.step(ToolPose(0.0, REST_TIP + 0.001, 0.0), detail=True)
    c = r.detail.contacts
    assert c.attach_idx.dtype == np.int64 and c.attach_idx.shape == (r.grasped.size,)
    assert c.attach_target.dtype == np.float64 and c.attach_target.shape == (r.grasped.size, 2)
    assert c.attach_compliance == sim.params.grasp_compliance and c.attach_stiffness == 1.0 / c.attach_compliance
    np.testing.assert_allclose(c.attach_target, sim.grasp.targets(ToolPose(0.0, REST_TIP + 0.001, 0.0)))
