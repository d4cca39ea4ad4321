"""The failure checks (bench/failures.py) on hand-built states whose verdict is known."""
from __future__ import annotations

import math

import numpy as np

from tissue_sim_ros.bench.failures import residual_falls
from tissue_sim_ros.core import health
from tissue_sim_ros.core.contact.tool import ToolPose, ToolShape
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams

BOX = ToolShape("box", length=0.4, width=0.01)


def _model() -> Model:
    return Model.from_mesh(mesh_rectangle(0.4, 0.2, 0.05), SimParams(boundary_y_top=0.19, boundary_y_bottom=0.01))


def test_nonfinite() -> None:
    x = np.zeros((3, 2))
    assert not health.has_nonfinite(x, x)
    x[1, 0] = np.nan
    assert health.has_nonfinite(np.zeros((3, 2)), x)
    x[1, 0] = -np.inf
    assert health.has_nonfinite(x)


def test_inverted_triangles_include_degenerate_ones() -> None:
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, 0.0]])
    tris = np.array([[0, 1, 2],    # CCW: fine
                     [0, 2, 1],    # CW: inverted
                     [0, 1, 4]])   # collinear: zero area counts as inverted
    np.testing.assert_array_equal(health.inverted_triangles(x, tris), [1, 2])


def test_tunnelling_box_moving_through_a_particle() -> None:
    # a box 0.4 x 0.01 moving down by 0.05 m past a particle at rest 0.02 below its centre
    x = np.array([[0.0, -0.02], [0.3, -0.02], [0.0, 0.1]])
    pose0, pose1 = ToolPose(0.0, 0.0), ToolPose(0.0, -0.05)
    hit = health.tunnelled_particles(x, x, pose0, pose1, BOX)
    np.testing.assert_array_equal(hit, [0])  # 0.3 is beyond the box's end; 0.1 is behind it
    # the same particle pushed ahead of the tool does not tunnel
    pushed = x.copy()
    pushed[0, 1] = -0.06
    assert health.tunnelled_particles(x, pushed, pose0, pose1, BOX).size == 0
    # a particle resting on the surface (inside by less than the tolerance) does not count
    on_surface = np.array([[0.0, -0.005 + 5e-5]])
    assert health.tunnelled_particles(on_surface, on_surface, pose0, pose0, BOX).size == 0
    # a particle ending inside the tool is penetration, not tunnelling; the depth is measured
    inside = np.array([[0.0, -0.052]])  # 2 mm above the lowered centre, 3 mm deep
    assert health.tunnelled_particles(inside, inside, pose0, pose1, BOX).size == 0
    assert math.isclose(health.penetration_depth(inside, pose1, BOX), 0.003, rel_tol=1e-9)
    assert health.penetration_depth(inside, pose1, BOX, movable=np.array([False])) == 0.0
    assert health.penetration_depth(x, pose0, BOX) == 0.0
    # an immovable particle is not checked for tunnelling
    assert health.tunnelled_particles(x, x, pose0, pose1, BOX, movable=np.array([False, True, True])).size == 0


def test_tunnelling_rotated_tool() -> None:
    # the box turned upright (yaw 90 deg) sweeping along +x through a particle at x = 0.03
    x = np.array([[0.03, 0.0]])
    pose0, pose1 = ToolPose(0.0, 0.0, math.pi / 2), ToolPose(0.06, 0.0, math.pi / 2)
    assert health.tunnelled_particles(x, x, pose0, pose1, BOX).size == 1
    assert health.tunnelled_particles(x, x + [0.06, 0.0], pose0, pose1, BOX).size == 0


def test_energy_bound_and_kinetic_energy() -> None:
    m = np.full(4, 0.5)
    v = np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 0.0], [3.0, 4.0]])
    assert health.kinetic_energy(m, v) == 0.25 * (1 + 4 + 25)
    # all 2 kg at tool speed 1 + g t = 9.8 * 0.1 + floor 0.1
    assert math.isclose(health.plausible_kinetic_energy(2.0, 1.0, -9.8, 0.1), 0.5 * 2.0 * (1.0 + 0.98 + 0.1) ** 2)


def test_residual_falls() -> None:
    assert residual_falls([1e-2, 3e-3, 1e-4])
    assert not residual_falls([1e-2, 2e-2, 5e-1])   # diverging Jacobi
    assert not residual_falls([1e-2, 9e-3])          # barely moving
    assert not residual_falls([1e-2, math.nan])
    assert residual_falls([0.0, 0.0])


def test_monitor_first_failure_of_each_kind() -> None:
    model = _model()
    x = model.particle_q0.copy()
    v = np.zeros_like(x)
    quiet = health.FailureMonitor(model, BOX)
    assert quiet.observe(1, x, x, v, 0.01) is None and quiet.first is None

    mon = health.FailureMonitor(model, BOX)
    assert mon.observe(1, x, x, v, 0.01, diverged=True).kind == "nonfinite"

    mon = health.FailureMonitor(model, BOX)
    fast = np.where(model.particle_inv_mass[:, None] > 0, 50.0, 0.0) * np.ones_like(x)
    assert mon.observe(1, x, x, fast, 0.01, tool_speed=1.0).kind == "energy_growth"
    assert mon.max_kinetic_ratio > 100
    # tissue pushed by a fast tool keeps its speed after the tool stops: not a failure
    mon = health.FailureMonitor(model, BOX)
    pushed = np.where(model.particle_inv_mass[:, None] > 0, 20.0, 0.0) * np.ones_like(x)
    assert mon.observe(1, x, x, pushed, 0.01, tool_speed=20.0) is None
    assert mon.observe(2, x, x, pushed, 0.02, tool_speed=0.0) is None

    # one triangle flipped: a failure only once it stays flipped for inverted_steps steps
    mon = health.FailureMonitor(model, BOX, inverted_steps=3)
    t = model.tri_indices[len(model.tri_indices) // 2]
    flipped = x.copy()
    flipped[t[0]], flipped[t[1]] = x[t[1]].copy(), x[t[0]].copy()
    assert mon.observe(1, x, flipped, v, 0.01) is None
    assert mon.observe(2, flipped, flipped, v, 0.02) is None
    assert mon.observe(3, flipped, x, v, 0.03) is None  # recovered: the count restarts
    for k in range(4, 6):
        assert mon.observe(k, x, flipped, v, 0.01 * k) is None
    failure = mon.observe(6, flipped, flipped, v, 0.06)
    assert failure is not None and failure.kind == "inverted" and failure.step == 6

    # the tool sweeping down through the strip's middle without the tissue moving
    mon = health.FailureMonitor(model, BOX)
    failure = mon.observe(1, x, x, v, 0.01, pose0=ToolPose(0.2, 0.16), pose1=ToolPose(0.2, 0.04), tool_speed=12.0)
    assert failure is not None and failure.kind == "tunnelling"
    assert mon.first == failure
    # later failures do not replace the first
    mon.observe(2, x, x, v, 0.02, diverged=True)
    assert mon.first.kind == "tunnelling"


def test_a_collapsed_or_overstrained_tissue_is_a_failure_at_once() -> None:
    """A 10 s step folds the tissue onto itself: most triangles flip, back and forth from step to step, so the
    consecutive-steps test never fires; a share of triangles inverted at one step does (``collapsed``). A tissue
    stretched to twice its size everywhere is past any tissue's tearing strain (``overstrained``)."""
    COLLAPSE_FRACTION, STRAIN_LIMIT, RunHealth = health.COLLAPSE_FRACTION, health.STRAIN_LIMIT, health.RunHealth

    model = _model()
    x = model.particle_q0.copy()
    v = np.zeros_like(x)
    mirrored = x * [-1.0, 1.0]  # every triangle clockwise: inverted
    assert health.FailureMonitor(model).observe(1, x, mirrored, v, 0.01) is None  # off unless asked (the benches)
    failure = health.FailureMonitor(model, collapse_fraction=COLLAPSE_FRACTION).observe(1, x, mirrored, v, 0.01)
    assert failure.kind == "collapsed" and f"{len(model.tri_indices)} of {len(model.tri_indices)}" in failure.detail

    centre = x.mean(axis=0)
    stretched = centre + 2.0 * (x - centre)
    failure = health.FailureMonitor(model, strain_limit=STRAIN_LIMIT).observe(1, x, stretched, v, 0.01)
    assert failure.kind == "overstrained"
    # a few edges stretched far (a tool's or a grasp's neighbourhood) are not the tissue overstrained
    local = x.copy()
    local[model.tri_indices[0]] += 0.1
    assert health.FailureMonitor(model, strain_limit=STRAIN_LIMIT).observe(1, x, local, v, 0.01) is None

    run = RunHealth(model, 0.01)
    run.observe(1, x)
    assert run.failure is None and run.verdict() == "yes"
    run.observe(2, mirrored, v)
    assert run.verdict().startswith("no: collapsed at step 2 (")
