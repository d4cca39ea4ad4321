"""A candidate's rollout in one compiled call (core/sim/fused.py) against the same path stepped one
Simulation.step at a time (test/naive.py:rollout_stepped): the same bits, for a grasper pulling the flap it holds
(the retraction scene) and for a tool pressing into a neo-Hookean tissue (contacts on particles and on surface
edges); the stepped path where the fused one does not apply."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.contact.tool import ToolPose
from tissue_sim_ros.core.resources import scene_params_file
from tissue_sim_ros.core.sim.batch import BatchScene, ToolPath, rollout_candidate
from tissue_sim_ros.core.sim.fused import FusedWorkspace, fused_applies, rollout_fused
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.core.sim.simulation import Simulation
from tissue_sim_ros.experiments.retract import grasp_and_lift

from naive import rollout_stepped


def _held_flap(spacing: float = 0.005) -> tuple[Simulation, ToolPose]:
    """The retraction scene (a coarse mesh: small and quick) on the whole-step solve with projection contact (the
    fused rollout's solver), the flap grasped and lifted 5 mm."""
    cfg = resolve_config(params_file=[scene_params_file("retract")]).replace(
        spacing=spacing, method="quasi_newton", contact_model="projection")
    sim = Simulation.from_config(cfg)
    pose = grasp_and_lift(sim, 10)
    assert sim.grasp.n_held > 0
    return sim, pose


def _pull(pose: ToolPose, angle_deg: float, turn: float, steps: int = 30) -> np.ndarray:
    a = np.radians(angle_deg)
    k = np.arange(1, steps + 1)
    return np.stack([pose.x + 4e-4 * k * np.cos(a), pose.y + 4e-4 * k * np.sin(a), pose.yaw + turn * k], axis=1)


def _same(sim: Simulation, snap, poses: np.ndarray, start: ToolPose) -> None:
    ws = FusedWorkspace(sim)
    out = rollout_fused(sim, snap, poses, start, ws)
    assert out["steps"] == len(poses)
    x, v, energy, force, pen = rollout_stepped(sim, snap, poses, start)
    assert np.array_equal(out["x"], x) and np.array_equal(out["v"], v)
    e = out["energy_body"]
    assert np.array_equal((e[:, :, 0] + e[:, :, 1] + e[:, :, 2] + e[:, :, 3] + e[:, :, 4]).sum(axis=1), energy)
    assert np.array_equal(out["force"], force)
    assert np.array_equal(out["penetration"], pen)


@pytest.mark.parametrize("angle,turn", [(60.0, 0.0), (-30.0, 0.01), (180.0, -0.02)])
def test_a_held_flap_pulled_is_the_stepped_rollout_bit_for_bit(angle, turn):
    sim, pose = _held_flap()
    snap = sim.snapshot()
    scratch = BatchScene.from_simulation(sim).build()
    assert fused_applies(scratch, snap, None)
    _same(scratch, snap, _pull(pose, angle, turn), pose)
    # through rollout_candidate too: every number and the final state, fused or stepped
    path = ToolPath(_pull(pose, angle, turn))
    a = rollout_candidate(scratch, snap, path, 0, True, fused=True)
    b = rollout_candidate(scratch, snap, path, 0, True, fused=False)
    assert a.metrics() == b.metrics()
    assert np.array_equal(a.energy, b.energy)
    assert np.array_equal(a.final_state.particle_q, b.final_state.particle_q)
    assert b.peak_force > 0.01  # the pull loads the grasp: the force is measured, not zero


@pytest.mark.parametrize("surface", ["particles", "edges"])
def test_a_tool_pressing_into_the_material_is_the_stepped_rollout_bit_for_bit(surface):
    sim = build_simulation({"tool_shape": "box", "tool_length": 0.3, "tool_width": 0.005, "material": "neo_hookean",
                            "contact_model": "projection", "contact_surface": surface})
    for _ in range(3):
        sim.step(None)
    snap = sim.snapshot()
    x = snap.particle_q
    top = float(x[:, 1].max())
    cx = float(np.median(x[:, 0]))
    start = ToolPose(cx, top + 0.01, -np.pi / 2)  # the box's long axis vertical, its end just above the tissue
    k = np.arange(1, 31)
    poses = np.stack([cx + 0.0005 * k, top + 0.01 - 0.0015 * k, -np.pi / 2 + 0.003 * k], axis=1)
    _same(sim, snap, poses, start)
    path = ToolPath(poses, start=start)
    r = rollout_candidate(sim, snap, path, 0, True)
    assert r.contact_steps > 5 and r.peak_force > 0  # the tool pushed the tissue: contacts were solved


def test_the_stepped_path_where_the_fused_one_does_not_apply():
    sim, pose = _held_flap()
    snap = sim.snapshot()
    jaws = np.full(30, np.nan)
    jaws[10] = 0.8  # the path opens the jaw: stepped
    assert not fused_applies(sim, snap, jaws)
    assert fused_applies(sim, snap, np.full(30, np.nan))
    cfg = resolve_config(params_file=[scene_params_file("retract")]).replace(
        method="xpbd", substeps=10, iterations=10, contact_model="projection")
    xpbd = Simulation.from_config(cfg)
    assert not fused_applies(xpbd, xpbd.snapshot(), None)  # another solver: stepped
    barrier = Simulation.from_config(resolve_config(params_file=[scene_params_file("retract")]))
    assert barrier.params.method == "ipc" and not fused_applies(barrier, barrier.snapshot(), None)
    opening = sim.snapshot()
    opening.grasp = {**opening.grasp, "jaw": 0.8}  # closed, but the jaw reads open: the first step lets go
    assert not fused_applies(sim, opening, None)
