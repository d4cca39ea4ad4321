"""Run-time tool checks (core/contact/tool_checks.py): the kernel against its brute-force twin, and in a Simulation."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.contact.tool import ToolPose, ToolShape, tool_shape_array
from tissue_sim_ros.core.contact.tool_checks import INSIDE_TOL, tool_checks
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.sim.simulation import Simulation

import naive

SHAPES = [ToolShape(kind="box", length=0.06, width=0.01), ToolShape(kind="sphere", radius=0.012),
          ToolShape(kind="capsule", length=0.05, radius=0.004)]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_tool_checks_match_naive(shape, seed) -> None:
    rng = np.random.default_rng(seed)
    mesh = mesh_rectangle(0.1, 0.06, 0.01)
    x0 = mesh.vertices + rng.normal(0, 0.001, mesh.vertices.shape)
    x1 = x0 + rng.normal(0, 0.01, x0.shape)  # large moves: some particles cross the tool
    pose0 = ToolPose(0.05 + rng.uniform(-0.01, 0.01), 0.03, rng.uniform(-1, 1))
    pose1 = ToolPose(pose0.x + rng.uniform(-0.02, 0.02), pose0.y + rng.uniform(-0.02, 0.02), pose0.yaw + 0.2)
    s0, s1 = tool_shape_array(shape, pose0), tool_shape_array(shape, pose1)
    got = tool_checks(x0, x1, s0, s1, mesh.triangles, INSIDE_TOL)
    want = naive.tool_checks(x0, x1, s0, s1, mesh.triangles)
    assert got[0] == want[0] and got[2] == want[2] and got[4] == want[4]
    assert got[1] == pytest.approx(want[1], rel=1e-12, abs=1e-15)
    assert got[3] == want[3]
    assert got[0] > 0 and got[4]  # the tool sits in the middle of the tissue: these cases are exercised


def scene(contact_model: str, tool: ToolShape) -> Simulation:
    p = SimParams(method="xpbd", contact_model=contact_model, gravity=0.0, boundary_y_bottom=1e-9,
                  contact_margin=0.0)
    return Simulation(Model.from_mesh(mesh_rectangle(0.1, 0.04, 0.01), p), tool=tool)


def test_a_tool_without_contact_is_buried_and_penetrates() -> None:
    sim = scene("none", ToolShape(kind="sphere", radius=0.006))
    r = sim.step(ToolPose(0.05, 0.02, 0.0))
    assert r.tool_buried and r.n_penetrating >= 1
    assert r.penetration_depth == pytest.approx(0.006, abs=1e-9)  # a particle at the sphere's centre
    assert r.deepest_particle >= 0


def test_a_fast_tool_tunnels_through_a_row_unseen_by_the_end_state() -> None:
    """The tool jumps across the top row in one step without contact: the particles end outside it."""
    sim = scene("none", ToolShape(kind="box", length=0.2, width=0.004))
    sim.step(ToolPose(0.05, 0.045, 0.0))
    r = sim.step(ToolPose(0.05, 0.035, 0.0))  # top row at y = 0.04 swept by the box moving down 1 cm
    assert r.n_penetrating == 0
    assert r.n_tunnelled == 11


def test_projection_contact_keeps_the_counters_at_zero() -> None:
    sim = scene("projection", ToolShape(kind="box", length=0.2, width=0.004))
    for k in range(10):
        r = sim.step(ToolPose(0.05, 0.045 - 0.0005 * k, 0.0))
    assert r.n_contact_particles > 0
    assert (r.n_penetrating, r.n_tunnelled, r.tool_buried) == (0, 0, False)
    assert math.isfinite(r.reaction_force[1]) and r.reaction_force[1] > 0


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("kind", ["capsule", "grasper"])
def test_outline_checks_match_naive(kind, seed) -> None:
    """The barrier contact's checks against the tool's polygons (outline_checks) and their NumPy twin, on large
    random moves that put particles inside the tool, carry others through it, and bury it."""
    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.core.contact.collider import core_positions, pose_dofs
    from tissue_sim_ros.core.contact.tool_checks import outline_checks

    extra = {"tool_shape": "capsule", "tool_length": 0.04, "tool_radius": 0.005} if kind == "capsule" else \
        {"tool_shape": "grasper"}
    cfg = resolve_config({"material": "neo_hookean", "spacing": 0.01, **extra})
    assert cfg.sim.contact_model == "barrier"
    mesh = mesh_rectangle(0.1, 0.06, 0.01)
    sim = Simulation.from_config(cfg, mesh=mesh)
    geom = sim._geometry
    rng = np.random.default_rng(seed)
    x0 = mesh.vertices + rng.normal(0, 0.001, mesh.vertices.shape)
    x1 = x0 + rng.normal(0, 0.01, x0.shape)
    p0 = ToolPose(0.05 + rng.uniform(-0.01, 0.01), 0.03, rng.uniform(-1, 1))
    p1 = ToolPose(p0.x + rng.uniform(-0.02, 0.02), p0.y + rng.uniform(-0.02, 0.02), p0.yaw + 0.2)
    pos1 = core_positions(pose_dofs(p1, 0.5), geom)
    frames = [np.array([p.x, p.y, math.cos(p.yaw), math.sin(p.yaw)]) for p in (p0, p1)]
    got = outline_checks(x0, x1, frames[0], frames[1], pos1, geom.edges, geom.loop_ptr, mesh.triangles, INSIDE_TOL)
    want = naive.outline_checks(x0, x1, frames[0], frames[1], pos1, geom.edges, geom.loop_ptr, mesh.triangles)
    assert (got[0], got[2], got[3], got[4]) == (want[0], want[2], want[3], want[4])
    assert got[1] == pytest.approx(want[1], rel=1e-12, abs=1e-15)
    assert got[0] > 0 and got[4]  # inside and buried are exercised (tunnelling: in some seeds, and below)


def test_outline_tunnelling_counts_a_path_through_the_tool_not_one_around_a_corner() -> None:
    """Through: a particle from left of the capsule to right of it, the tool still. Around: particles that slid
    along the rounded tip, their chords just cutting one corner of its polygon (two crossed edges facing the same
    way), as the barrier step leaves them (it never lets one through)."""
    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.core.contact.collider import core_positions, pose_dofs
    from tissue_sim_ros.core.contact.tool_checks import outline_checks

    cfg = resolve_config({"material": "neo_hookean", "tool_shape": "capsule", "tool_length": 0.03,
                          "tool_radius": 0.0025, "spacing": 0.01})
    sim = Simulation.from_config(cfg, mesh=mesh_rectangle(0.1, 0.06, 0.01))
    geom = sim._geometry
    pose = ToolPose(0.05, 0.05, -0.5 * math.pi)  # upright, tip down at y = 0.05 - 0.015 - 0.0025
    pos = core_positions(pose_dofs(pose, 0.0), geom)
    frame = np.array([pose.x, pose.y, math.cos(pose.yaw), math.sin(pose.yaw)])
    tip = np.array([0.05, 0.05 - 0.015])  # the centre of the tip's rounded end
    tri = np.zeros((0, 3), dtype=np.int64)
    # through the shaft: from 1 cm left to 1 cm right at the shaft's middle
    x0, x1 = np.array([[0.04, 0.05]]), np.array([[0.06, 0.05]])
    assert outline_checks(x0, x1, frame, frame, pos, geom.edges, geom.loop_ptr, tri, INSIDE_TOL)[3] == 1
    assert naive.outline_checks(x0, x1, frame, frame, pos, geom.edges, geom.loop_ptr, tri)[3] == 1
    # around: points 1 um outside the tip's polygon (outside its circumscribed circle), 8.6 degrees apart; their
    # chords dip 7 um inward and cut its corners
    r = float(np.hypot(*(pos - tip).T)[np.hypot(*(pos - tip).T) < 0.003].max()) + 1e-6
    angles = np.linspace(-0.5 * math.pi - 0.6, -0.5 * math.pi + 0.6, 9)
    pts = tip + r * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    x0, x1 = pts[:-1], pts[1:]
    got = outline_checks(x0, x1, frame, frame, pos, geom.edges, geom.loop_ptr, tri, INSIDE_TOL)
    want = naive.outline_checks(x0, x1, frame, frame, pos, geom.edges, geom.loop_ptr, tri)
    assert got[3] == want[3] == 0 and got[0] == want[0] == 0
    # the same chords, counted by crossings alone (the check before it compared the facing of the edges), cut corners
    crossed = sum(
        sum(naive_cross(p0, p1, pos[a], pos[b]) for a, b in geom.edges) >= 2 for p0, p1 in zip(x0, x1))
    assert crossed > 0


def naive_cross(p, q, a, b) -> bool:
    """Segments p-q and a-b cross properly."""
    def cx(u, w):
        return u[0] * w[1] - u[1] * w[0]
    return cx(q - p, a - p) * cx(q - p, b - p) < 0 and cx(b - a, p - a) * cx(b - a, q - a) < 0
