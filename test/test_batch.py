"""Snapshots and batch rollouts: a restored scene continues bit for bit; pool == serial == one by one.

Every comparison is ``np.array_equal`` (bit-identical), not a tolerance:
the same compiled kernels on the same inputs in any process give the same
bits, and a snapshot holds everything a step reads that an earlier step wrote.
"""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from tissue_sim_ros.core.contact.tool import StraightInsertion, ToolPose
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.sim.batch import (
    BaselineTrack,
    BatchScene,
    RolloutPool,
    ToolPath,
    as_tool_path,
    rollout_batch,
    rollout_candidate,
)
from tissue_sim_ros.core.sim.rollout import rollout
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.core.sim.snapshot import SimSnapshot
from tissue_sim_ros.core.timing import trajectories as tr

B_TOOL = {"tool_shape": "box", "tool_length": 0.3, "tool_width": 0.005}


def _sim(**over):
    return build_simulation({**B_TOOL, "contact_model": "projection", **over})


def _insertion(sim, angle_deg, speed=0.004, distance=0.12):
    # short and fast: reaches the lower tissue within ~30 steps
    return tr.experiment_b(sim.tool, sim.params.dt, angle_deg, speed=speed, distance=distance)


def _drive(sim, traj, n):
    """Step ``sim`` ``n`` steps of ``traj``; the reports' energies and the final state."""
    energies = []
    for k, (pose, twist) in enumerate(traj.steps(sim.params.dt)):
        if k == n:
            break
        energies.append(sim.step(pose, twist).energy.scene_total)
    return np.array(energies)


@pytest.mark.parametrize("over", [{}, {"contact_model": "paper"}, {"method": "xpbd"},
                                  {"sleep_speed": 0.05, "sleep_wake_radius": 0.1}],
                         ids=["projection", "paper", "xpbd", "sleeping"])
def test_restore_continues_bit_for_bit(over):
    sim = _sim(**over)
    traj = _insertion(sim, -30.0)
    steps = list(traj.steps(sim.params.dt))
    for pose, twist in steps[:15]:
        sim.step(pose, twist)
    snap = pickle.loads(pickle.dumps(sim.snapshot()))  # plain data: survives a trip to another process
    assert isinstance(snap, SimSnapshot) and snap.step_count == 15 and snap.tool_pose == steps[14][0]
    original = [sim.step(p, t) for p, t in steps[15:30]]
    # into a fresh simulation of the same scene (fresh workspaces) and back into the original
    for target in (_sim(**over), sim):
        target.restore(snap)
        again = [target.step(p, t) for p, t in steps[15:30]]
        assert target.step_count == 30 and math.isclose(target.time, 0.30)
        for a, b in zip(original, again):
            assert np.array_equal(a.energy.total, b.energy.total)
            assert np.array_equal(a.reaction_force, b.reaction_force)
            assert np.array_equal(a.contact_particles, b.contact_particles)
    assert np.array_equal(target.state.particle_q, sim.state.particle_q)
    assert any(r.n_contact_particles for r in original), "the tool should touch the tissue in these steps"


def test_sleeping_snapshot_carries_the_sleeping_set():
    sim = _sim(sleep_speed=0.05, sleep_wake_radius=0.1)
    for _ in range(30):
        sim.step(None)
    snap = sim.snapshot()
    assert snap.solver["sleeping"].any(), "particles far from any tool should sleep after 30 quiet steps"
    fresh = _sim(sleep_speed=0.05, sleep_wake_radius=0.1)
    fresh.restore(snap)
    assert np.array_equal(fresh.solver.sleeping, sim.solver.sleeping)


def test_restore_refuses_another_scene():
    snap = _sim().snapshot()
    other = _sim(spacing=0.08)
    with pytest.raises(InputError, match="snapshot of scene"):
        other.restore(snap)
    with pytest.raises(InputError, match="expected a SimSnapshot"):
        other.restore({"particle_q": 0})


def test_tool_path_checks_its_input():
    with pytest.raises(InputError, match=r"expected \(S, 3\)"):
        ToolPath(np.zeros((4, 2)))
    with pytest.raises(InputError, match="finite"):
        ToolPath(np.full((2, 3), np.nan))
    with pytest.raises(InputError, match="twists"):
        ToolPath(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(InputError, match="no candidate"):
        rollout_batch(_sim(), [])


@pytest.fixture(scope="module")
def live():
    """A scene 20 steps into an insertion (the tool in contact), and four candidate insertions."""
    sim = _sim()
    first = _insertion(sim, -20.0)
    _drive(sim, first, 25)
    cands = [_insertion(sim, a, speed=s) for a in (-15.0, -35.0) for s in (0.003, 0.005)]
    return sim, cands


def test_batch_serial_matches_plain_rollouts_one_by_one(live):
    sim, cands = live
    snap = sim.snapshot()
    res = rollout_batch(sim, cands, final_state=True)
    assert sim.step_count == 25, "the source simulation is not stepped by a batch"
    # the tool-free baseline and each candidate, with the plain rollout of core/sim/rollout.py
    base_sim = build_simulation({**B_TOOL, "contact_model": "projection"})
    base_sim.restore(snap)
    base = rollout(base_sim, ((None, None) for _ in range(len(res.baseline_energy)))).scene_total
    assert np.array_equal(base, res.baseline_energy)
    for c, traj in zip(res.candidates, cands):
        one = build_simulation({**B_TOOL, "contact_model": "projection"})
        one.restore(snap)
        one.tool_pose = traj.pose_at(0.0)  # a new insertion: the tool is placed at its entry pose
        run = rollout(one, traj.steps(one.params.dt))
        assert np.array_equal(run.scene_total, c.energy)
        assert c.cost == float((run.scene_total - base[: c.steps]).sum())
        assert c.peak_force == float(np.linalg.norm(run.reaction_force, axis=1).max())
        assert np.array_equal(c.final_state.particle_q, one.state.particle_q)
        assert c.steps == traj.n_steps(one.params.dt) and c.finite and c.contact_steps > 0
        assert c.max_displacement > 0 and c.max_penetration >= 0
    assert res.best() == int(np.argmin(res.costs))


@pytest.mark.parametrize("over", [{}, {"contact_model": "paper"}, {"method": "xpbd"},
                                  {"sleep_speed": 0.05, "sleep_wake_radius": 0.1}, {"contact_surface": "edges"},
                                  {"contact_model": "none"}, {"material": "neo_hookean"}],
                         ids=["projection", "paper", "xpbd", "sleeping", "edges", "no-contact", "neo-hookean"])
def test_steps_beyond_reach_taken_from_the_baseline_are_the_solved_steps(over):
    """A candidate's leading steps with the tool beyond reach are the baseline's (BaselineTrack): every number
    and the final state equal a rollout that solves every step, with the track's memory ample or nearly full."""
    sim = _sim(**over)
    for _ in range(5):
        sim.step(None)
    snap = sim.snapshot()
    ample = BaselineTrack(sim, snap)
    tight = BaselineTrack(sim, snap, max_bytes=3 * 4 * snap.particle_q.nbytes)  # the snapshot and 2 steps
    skipped, lengths = [], []
    for angle in (-15.0, -35.0):
        path = as_tool_path(_insertion(sim, angle, speed=0.003), sim.params.dt)
        solved = rollout_candidate(sim, snap, path, 0, True)
        assert solved.baseline_steps == 0
        for track in (ample, tight):
            r = rollout_candidate(sim, snap, path, 0, True, track)
            assert r.metrics() == solved.metrics()
            assert np.array_equal(r.energy, solved.energy)
            assert np.array_equal(r.final_state.particle_q, solved.final_state.particle_q)
            assert np.array_equal(r.final_state.particle_qd, solved.final_state.particle_qd)
            assert sim.tool_pose == ToolPose(*path.poses[-1]) and sim.step_count == 5 + path.n_steps
        assert len(tight.states) == 3 and tight.steps >= 2
        skipped.append(rollout_candidate(sim, snap, path, 0, False, ample).baseline_steps)
        lengths.append(path.n_steps)
    # the insertions start outside the tissue: their approach is taken from the baseline (all of it without contact)
    assert max(skipped) > 0
    if over.get("contact_model") == "none":
        assert skipped == lengths
    ample.extend(max(lengths))
    batch = rollout_batch(snap, [path], scene=BatchScene.from_simulation(sim))
    assert np.array_equal(batch.baseline_energy, ample.energy[: path.n_steps])


def test_pool_results_are_bit_identical_to_serial(live):
    sim, cands = live
    snap = sim.snapshot()
    serial = rollout_batch(snap, cands, scene=BatchScene.from_simulation(sim), final_state=True)
    with RolloutPool(sim, workers=2) as pool:
        assert len(set(pool.pids)) == 2
        first = rollout_batch(snap, cands, pool=pool, final_state=True)
        # a second batch on the same warm workers, candidates in another order
        second = pool.run(snap, cands[::-1])
    assert first.workers == 2
    for s, p, q in zip(serial.candidates, first.candidates, second.candidates[::-1]):
        assert s.metrics() == p.metrics() == {**q.metrics(), "index": s.index}
        assert np.array_equal(s.energy, p.energy) and np.array_equal(s.energy, q.energy)
        assert np.array_equal(s.final_state.particle_q, p.final_state.particle_q)
        assert np.array_equal(s.final_state.particle_qd, p.final_state.particle_qd)
    assert np.array_equal(serial.baseline_energy, first.baseline_energy)


def test_pool_refuses_another_scene_and_follows_a_new_one(live):
    sim, cands = live
    other = _sim(spacing=0.08)
    with RolloutPool(sim, workers=1) as pool:
        with pytest.raises(InputError, match="pool's scene"):
            pool.run(other.snapshot(), cands[:1])
        pool.set_scene(other)
        res = pool.run(other.snapshot(), cands[:1])
    serial = rollout_batch(other, cands[:1])
    assert np.array_equal(res.candidates[0].energy, serial.candidates[0].energy)


def test_batch_cost_from_rest_is_the_plan_commands_cost():
    from tissue_sim_ros.experiments.plan import evaluate

    values = {**B_TOOL, "contact_model": "projection"}
    sim = build_simulation(values)
    traj = tr.experiment_b(sim.tool, sim.params.dt, -30.0, speed=0.004, distance=0.12)
    row = evaluate(values, -30.0, 0.004, tr.B_TARGET, 0.12)
    res = rollout_batch(sim, [traj])
    assert res.candidates[0].cost == row["cost"]
    assert res.candidates[0].peak_force == row["max_reaction_N"]


def test_pose_array_candidates_continue_from_the_snapshot_tool(live):
    sim, _ = live
    here = sim.tool_pose
    poses = np.array([[here.x + 0.001 * k, here.y, here.yaw] for k in range(1, 6)])
    path = as_tool_path(poses, sim.params.dt)
    assert path.start is None
    scene = BatchScene.from_simulation(sim)
    one = scene.build()
    r = rollout_candidate(one, sim.snapshot(), path)
    assert one.tool_pose == ToolPose(*poses[-1]) and r.steps == 5
    assert isinstance(_insertion(sim, -30.0), StraightInsertion)


def test_bench_plan_writes_its_table(tmp_path, capsys):
    from tissue_sim_ros.cli import main

    assert main(["bench", "plan", "--candidates", "3", "--steps", "5", "--repeats", "1", "--workers", "1",
                 "--no-node", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "identical" in out and "pool 1" in out and " NO" not in out
    rows = (tmp_path / "plan_bench.csv").read_text().splitlines()
    assert len(rows) == 4 and rows[0].startswith("backend,workers,candidates")
    assert (tmp_path / "plan_bench.png").stat().st_size > 1000
    assert main(["bench", "plan", "--candidates", "0", "--no-node", "--out", str(tmp_path)]) == 2


@pytest.mark.parametrize("angle,speed,hold", [(-30.0, 0.1, 0.0), (-72.5, 0.2333, 0.05), (45.0, 0.3, 0.0)])
def test_straight_paths_sampled_with_numpy_are_the_trajectory_loop_bit_for_bit(angle, speed, hold):
    from tissue_sim_ros.core.contact.tool import ToolShape, Trajectory

    traj = StraightInsertion.from_angle(ToolShape(kind="box", length=0.3), (0.55, 0.38), math.radians(angle), 0.2,
                                        speed, hold=hold)
    path = ToolPath.from_trajectory(traj, 0.01)
    rows = list(Trajectory.steps(traj, 0.01))  # the generic per-step loop
    assert np.array_equal(path.poses, [(p.x, p.y, p.yaw) for p, _ in rows])
    assert np.array_equal(path.twists, [(t.vx, t.vy, t.wz) for _, t in rows])
    assert path.start == traj.pose_at(0.0)
