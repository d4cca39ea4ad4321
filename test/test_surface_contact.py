"""Projection contact on the tissue's surface: boundary edges kept out of the tool (``contact_surface``).

A tool thinner than the mesh spacing slips between particles; the edge
contact keeps it on the outside of the boundary edges too, so it indents the
surface. Kernels are compared with the NumPy references in ``naive.py``
(random and degenerate input); simulations check a thin box pressing into a
coarse strip, a tool already deep inside, and the paper's experiment a.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.contact import collision as C
from tissue_sim_ros.core.contact import kernels as K
from tissue_sim_ros.core.contact.tool import ToolPose, ToolShape, tool_shape_array
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.sim.simulation import Simulation

import naive

BOX = ToolShape("box", length=0.8, width=0.005)
SHAPES = [BOX, ToolShape("capsule", length=0.3, radius=0.004), ToolShape("sphere", radius=0.02)]


def _random_edge(rng: np.random.Generator, centre, spread=0.06, length=(0.0, 0.08)):
    a = np.asarray(centre) + rng.uniform(-spread, spread, size=2)
    ang = rng.uniform(-math.pi, math.pi)
    return a, a + rng.uniform(*length) * np.array([math.cos(ang), math.sin(ang)])


def point_in_triangles(x: np.ndarray, tris: np.ndarray, p: np.ndarray) -> int:
    """How many triangles strictly contain point p (CCW triangles: all three edge tests positive)."""
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]

    def side(u, v):
        return (v[:, 0] - u[:, 0]) * (p[1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[0] - u[:, 0])

    return int(np.count_nonzero((side(a, b) > 0) & (side(b, c) > 0) & (side(c, a) > 0)))


# --------------------------------------------------------------------------- kernels vs NumPy


def test_boundary_edges_are_the_once_used_edges_with_the_body_on_the_left():
    rng = np.random.default_rng(0)
    for mesh in (mesh_rectangle(1.0, 0.3, 0.1), mesh_rectangle(0.4, 0.4, 0.05, origin=(1.0, 2.0))):
        edges = C.boundary_edges_ccw(mesh.triangles)
        np.testing.assert_array_equal(edges, naive.boundary_edges_ccw(mesh.triangles))
        x = mesh.vertices
        # the inward normal points into the strip: a point just inside along it is in the rectangle
        e = x[edges[:, 1]] - x[edges[:, 0]]
        n_in = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
        inner = 0.5 * (x[edges[:, 0]] + x[edges[:, 1]]) + 1e-3 * n_in
        lo, hi = x.min(axis=0), x.max(axis=0)
        assert np.all((inner > lo) & (inner < hi))
        assert len(edges) == 2 * (round((hi - lo)[0] / (x[1, 0] - x[0, 0])) + round((hi - lo)[1] / (x[1, 0] - x[0, 0])))
    # degenerate: no triangles
    assert C.boundary_edges_ccw(np.zeros((0, 3), np.int32)).shape == (0, 2)
    del rng


@pytest.mark.parametrize("tool", SHAPES, ids=lambda t: t.kind)
def test_edge_depth_matches_naive(tool):
    rng = np.random.default_rng(11)
    for trial in range(30):
        margin = float(rng.choice([0.0, 0.002]))
        s = tool_shape_array(tool, ToolPose(0.0, 0.0, rng.uniform(-math.pi, math.pi)), margin)
        # edges near the tool's end (the tip) or its middle
        centre = tool_shape_array(tool, ToolPose(0.0, 0.0, 0.0))[4] * np.array([s[2], s[3]]) * rng.choice([0.0, 1.0])
        a, b = _random_edge(rng, centre, length=(0.001, 0.08))
        depth, t, line = K.edge_depth(a[0], a[1], b[0], b[1], s)
        d_ref, t_ref, line_ref = naive.edge_depth(a, b, s, samples=24 if trial % 5 == 0 else 0)
        assert line == pytest.approx(line_ref, abs=1e-12)
        if d_ref == -np.inf:
            assert depth == -np.inf
            continue
        assert depth == pytest.approx(d_ref, abs=1e-9)
        assert 0.0 <= t <= 1.0
        # the point at t reaches that depth (also where the maximiser is not unique)
        u_hat = (b - a) / np.linalg.norm(b - a)
        n = np.array([-u_hat[1], u_hat[0]])
        reach = naive.deepest_on_line(a + t * (b - a), n, s)
        assert reach == pytest.approx(depth, abs=1e-9)


def test_edge_depth_degenerate_inputs():
    s = tool_shape_array(BOX, ToolPose(0.0, 0.0, -math.pi / 2), 0.0)  # vertical, tip at (0, -0.4)
    tip = np.array([0.0, -0.4])
    # zero-length edge: no direction, no depth
    assert K.edge_depth(0.0, -0.39, 0.0, -0.39, s)[0] == -np.inf
    # the tip exactly on an edge vertex (edge right to left, body below): depth 0, at the part of the
    # tip's flat 5 mm end face (parallel to the edge) over the span: x in [0, 0.0025] -> t = 0.975
    d, t, _ = K.edge_depth(0.05, -0.4, 0.0, -0.4, s)
    assert d == pytest.approx(0.0, abs=1e-12) and t == pytest.approx(0.975, abs=1e-12)
    assert K.edge_depth(0.0, -0.4, -0.05, -0.4, s)[1] == pytest.approx(0.025, abs=1e-12)
    # the tip 1 mm past the edge, between its particles: pushed at the tip's place
    d, t, _ = K.edge_depth(0.04, -0.399, -0.06, -0.399, s)
    assert d == pytest.approx(0.001, abs=1e-12) and t == pytest.approx(0.4, abs=1e-12)
    # an edge parallel to the tool's side (the box's long face at x = 0.0025, y in [-0.4, 0.4]): a -> b going
    # down has its body on the right (+x), so the face is the support set, 0.5 mm past the edge, taken at
    # the middle of its overlap with the span (y in [0.1, 0.4] of [0.1, 0.5]: t = 0.625)
    d, t, _ = K.edge_depth(0.002, 0.5, 0.002, 0.1, s)
    assert d == pytest.approx(0.0005, abs=1e-12) and t == pytest.approx(0.625, abs=1e-12)
    d_ref, t_ref, _ = naive.edge_depth(np.array([0.002, 0.5]), np.array([0.002, 0.1]), s, samples=101)
    assert (d, t) == pytest.approx((d_ref, t_ref), abs=1e-12)
    # a face parallel to an edge entirely beside its span: nothing in the strip
    assert K.edge_depth(0.002, 0.5, 0.002, 0.6, s)[0] == -np.inf
    # the tool on the outer side of the edge: negative depth
    d, _, line = K.edge_depth(0.05, -0.45, -0.05, -0.45, s)
    assert d < 0 and line < 0
    del tip


def test_project_edges_matches_naive():
    rng = np.random.default_rng(5)
    xs = np.linspace(-0.1, 0.1, 6)
    for trial in range(40):
        tool = SHAPES[trial % len(SHAPES)]
        margin = float(rng.choice([0.0, 0.002]))
        yaw = -math.pi / 2 + rng.uniform(-0.6, 0.6)
        hx = tool_shape_array(tool, ToolPose(0, 0, 0))[4] + tool_shape_array(tool, ToolPose(0, 0, 0))[6]
        tip0 = np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.0, 0.01)])
        tip1 = tip0 + rng.uniform(-0.02, 0.005, size=2) * np.array([0.3, 1.0])
        s0 = tool_shape_array(tool, ToolPose(tip0[0] - hx * math.cos(yaw), tip0[1] - hx * math.sin(yaw), yaw), margin)
        s1 = tool_shape_array(tool, ToolPose(tip1[0] - hx * math.cos(yaw), tip1[1] - hx * math.sin(yaw), yaw), margin)
        # a surface along y ~ 0 (edges right to left: the body below), wiggled, its particles moved a little
        x_start = np.stack([xs[::-1], rng.normal(scale=0.002, size=len(xs))], axis=1)
        x = x_start + rng.normal(scale=0.001, size=x_start.shape)
        edges = np.stack([np.arange(len(xs) - 1), np.arange(1, len(xs))], axis=1).astype(np.int32)
        w = rng.choice([0.0, 1.0, 2.0], size=len(xs), p=[0.2, 0.4, 0.4])
        x_k, acc = x.copy(), np.zeros_like(x)
        moved = K.project_edges(x_k, x_start, w, edges, s0, s1, 0.002, acc)
        x_n, acc_n, moved_n = naive.project_edges(x, x_start, w, edges, s0, s1, 0.002)
        assert moved == moved_n
        np.testing.assert_allclose(x_k, x_n, atol=1e-9)
        np.testing.assert_allclose(acc, acc_n, atol=1e-9)
        assert np.all(acc[w == 0.0] == 0.0)


def test_project_edges_pushes_an_edge_under_the_tip_and_respects_pins():
    s = tool_shape_array(BOX, ToolPose(0.0, 0.4 + 0.01 - 0.001, -math.pi / 2), 0.001)  # tip 1 mm below y = 0.01
    tip_y = 0.01 - 0.001 - 0.001  # the inflated tip
    x_start = np.array([[0.05, -0.01], [-0.05, -0.01]])  # the edge below the tool at the start, then moved up
    for w, expect in (([1.0, 1.0], (0.5, 0.5)), ([1.0, 0.0], (1.0, 0.0)), ([2.0, 1.0], (2 / 3, 1 / 3))):
        x = np.array([[0.05, 0.01], [-0.05, 0.01]])
        acc = np.zeros_like(x)
        assert K.project_edges(x, x_start, np.array(w), np.array([[0, 1]], np.int32), s, s, 0.002, acc) == 1
        # the edge passes under the tip (t = 0.5) and moved only down, by the inverse-mass share
        assert 0.5 * (x[0, 1] + x[1, 1]) == pytest.approx(tip_y, abs=1e-12)
        np.testing.assert_allclose(acc[:, 0], 0.0, atol=1e-15)
        drop = 0.01 - x[:, 1]
        np.testing.assert_allclose(drop / drop.sum(), expect, atol=1e-12)
    # both pinned: nothing moves
    x = np.array([[0.05, 0.01], [-0.05, 0.01]])
    assert K.project_edges(x, x_start, np.zeros(2), np.array([[0, 1]], np.int32), s, s, 0.002, np.zeros((2, 2))) == 0
    # the tool already 5 cm through the edge at the start: left alone (no snap)
    deep = tool_shape_array(BOX, ToolPose(0.0, 0.4 + 0.01 - 0.05, -math.pi / 2), 0.001)
    x = np.array([[0.05, 0.01], [-0.05, 0.01]])
    assert K.project_edges(x, x.copy(), np.ones(2), np.array([[0, 1]], np.int32), deep, deep, 0.002,
                           np.zeros((2, 2))) == 0
    # a tool crossing the edge within one step (10 cm) is still pushed back to the outside (swept)
    s0 = tool_shape_array(BOX, ToolPose(0.0, 0.4 + 0.05, -math.pi / 2), 0.001)
    s1 = tool_shape_array(BOX, ToolPose(0.0, 0.4 - 0.05, -math.pi / 2), 0.001)
    x = np.array([[0.05, 0.01], [-0.05, 0.01]])
    assert K.project_edges(x, x.copy(), np.ones(2), np.array([[0, 1]], np.int32), s0, s1, 0.002, np.zeros((2, 2))) == 1
    assert 0.5 * (x[0, 1] + x[1, 1]) == pytest.approx(-0.05 - 0.001, abs=1e-12)


def test_swept_edge_candidates_match_naive_and_cover_the_sweep():
    rng = np.random.default_rng(9)
    model = Model.from_mesh(mesh_rectangle(1.0, 0.3, 0.1), SimParams())
    edges = C.boundary_edges_ccw(model.tri_indices)
    x = model.particle_q0 + rng.normal(scale=0.003, size=model.particle_q0.shape)
    inv_mass = np.where(rng.random(len(x)) < 0.2, 0.0, 1.0)
    out = np.empty(len(edges), np.int32)
    for tool in SHAPES:
        for _ in range(10):
            yaw = rng.uniform(-math.pi, math.pi)
            p0 = ToolPose(rng.uniform(0.0, 1.0), rng.uniform(0.25, 0.4), yaw)
            p1 = ToolPose(p0.x + rng.uniform(-0.05, 0.05), p0.y + rng.uniform(-0.05, 0.05), yaw + rng.uniform(-0.2, 0.2))
            s0, s1 = tool_shape_array(tool, p0, 0.002), tool_shape_array(tool, p1, 0.002)
            reach = rng.uniform(0.0, 0.02)
            n = K.swept_edge_candidates(x, inv_mass, edges, s0, s1, reach, out)
            np.testing.assert_array_equal(out[:n], naive.swept_edge_candidates(x, inv_mass, edges, s0, s1, reach))
            # conservative: an edge with a free particle and a sampled point within reach of either end pose is kept
            f = np.linspace(0.0, 1.0, 33)[:, None]
            for k, (a, b) in enumerate(edges):
                if inv_mass[a] == 0 and inv_mass[b] == 0:
                    continue
                pts = x[a] + f * (x[b] - x[a])
                if min(naive.rounded_box_sdf(pts, s0).min(), naive.rounded_box_sdf(pts, s1).min()) <= reach:
                    assert k in out[:n]


def test_contact_surface_parameter_is_validated():
    assert SimParams().contact_surface == "edges"
    with pytest.raises(InputError, match="contact_surface"):
        SimParams(contact_surface="faces")


def test_solver_refuses_surface_edges_outside_the_model():
    p = SimParams(contact_model="projection")
    model = Model.from_mesh(mesh_rectangle(0.2, 0.1, 0.05), p)
    sim = Simulation(model, BOX)
    contacts = C.Contacts.empty(1)
    contacts.surface_edges = np.array([[0, model.n_particles]], np.int32)
    with pytest.raises(InputError, match="surface_edges"):
        sim.solver.step(sim.state, model.state(), contacts, p.dt)


# --------------------------------------------------------------------------- simulations


def _coarse_strip(surface: str) -> Model:
    """A 1 m x 0.3 m strip meshed at 0.1 m (20x the tool's width), resting on its pinned bottom row."""
    p = SimParams(contact_model="projection", contact_surface=surface, boundary_y_bottom=0.001)
    return Model.from_mesh(mesh_rectangle(1.0, 0.3, 0.1), p)


def _press(surface: str, speed: float, depth: float = 0.09):
    """A vertical box pressing tip first at x = 0.55 (between two surface particles) ``depth`` below y = 0.3."""
    model = _coarse_strip(surface)
    sim = Simulation(model, BOX)
    hx = BOX.length / 2
    tip_x, tip_y0 = 0.55, 0.31
    n = int(round((0.01 + depth) / speed))
    top = np.flatnonzero(np.isclose(model.particle_q0[:, 1], 0.3))
    rows = []
    for k in range(1, n + 1):
        tip = np.array([tip_x, tip_y0 - speed * k])
        rep = sim.step(ToolPose(tip[0], tip[1] + hx, -math.pi / 2))
        assert not rep.diverged
        x = sim.state.particle_q
        # the surface height under the tip: the top boundary interpolated at x = tip_x
        order = top[np.argsort(x[top, 0])]
        surface_y = float(np.interp(tip_x, x[order, 0], x[order, 1]))
        rows.append((0.3 - tip[1], point_in_triangles(x, model.tri_indices, tip), surface_y,
                     float(rep.energy.total[0]), rep.reaction_force.copy(), rep.n_inverted))
    return rows


@pytest.mark.parametrize("speed", [0.001, 0.01])
def test_thin_tool_indents_a_coarse_strip_instead_of_slipping_between_particles(speed):
    rows = _press("edges", speed)
    depth = np.array([r[0] for r in rows])
    inside = np.array([r[1] for r in rows])
    surface_y = np.array([r[2] for r in rows])
    energy = np.array([r[3] for r in rows])
    fy = np.array([r[4][1] for r in rows])
    fx = np.array([r[4][0] for r in rows])
    assert inside.max() == 0  # the tip never ends a step inside a tissue triangle
    assert max(r[5] for r in rows) == 0  # no inverted triangle
    pressing = depth > 0.005
    # the surface under the tip is pushed down with the tip: never above the inflated tip (the tip
    # is outside), and at most 5 mm below it (the edge under it follows it down)
    tip_skin = 0.3 - depth[pressing] - 0.002
    assert np.all(surface_y[pressing] <= tip_skin + 1e-6)
    assert np.all(surface_y[pressing] >= tip_skin - 5e-3)
    # the energy rises with indentation and the tissue pushes back up, harder the deeper
    deep = depth > 0.02
    # against the push (up); the edge under the tip tilts on this coarse mesh with its diagonals all one
    # way, and the frictionless push follows its normal (measured |fx| / fy up to 0.39 at 1 mm per step)
    assert np.all(fy[deep] > 0) and np.all(np.abs(fx[deep]) < 0.5 * fy[deep])
    at = lambda values, d: values[np.argmin(np.abs(depth - d))]  # noqa: E731
    assert at(energy, 0.0) < at(energy, 0.03) < at(energy, 0.06) < at(energy, 0.09)
    assert at(fy, 0.03) < at(fy, 0.06) < at(fy, 0.09)


def test_particles_only_lets_the_thin_tool_pierce_the_coarse_strip():
    """The documented failure of ``contact_surface=particles``: the 5 mm tip passes between particles 0.1 m apart."""
    rows = _press("particles", 0.01)
    depth = np.array([r[0] for r in rows])
    inside = np.array([r[1] for r in rows])
    surface_y = np.array([r[2] for r in rows])
    assert inside[depth > 0.005].all()  # the tip sits inside a triangle from the first step past the surface
    assert np.all(np.abs(surface_y - 0.3) < 2e-3)  # and the surface is not pushed at all
    assert all(r[4][1] == 0.0 for r in rows)  # no reaction: nothing is touched


def test_tool_already_deep_inside_is_not_snapped_out():
    """A tool spawned 0.1 m inside the strip (between particles) then moved sideways: the tissue does not explode.

    The edges it is already through ignore it (the start-of-step side rule), and
    the next edge along the surface too (the tool is past its line, beside its span).
    """
    model = _coarse_strip("edges")
    sim = Simulation(model, BOX)
    hx = BOX.length / 2
    q_rest = None
    for k in range(0, 80):
        tip = (0.55 + 0.001 * k, 0.2)
        rep = sim.step(ToolPose(tip[0], tip[1] + hx, -math.pi / 2))
        assert not rep.diverged
        if k == 0:
            q_rest = sim.state.particle_q.copy()
    moved = np.linalg.norm(sim.state.particle_q - q_rest, axis=1)
    # the tool crossed the surface vertex at x = 0.6: that particle is pushed aside (particle contact),
    # by about how far the tool went past it, not snapped 0.1 m over the tip
    assert moved.max() < 0.04
    assert rep.n_inverted == 0


def test_experiment_a_projection_pushes_the_lower_tissue():
    """The paper's experiment a with projection contact: the tip indents the lower tissue and never enters it."""
    from tissue_sim_ros.core.sim.scene import build_simulation
    from tissue_sim_ros.core.timing.trajectories import experiment_a

    sim = build_simulation({"contact_model": "projection"})
    assert sim.params.contact_surface == "edges"
    m = sim.model
    low_body = m.particle_body[np.argmin(m.particle_q0[:, 1])]
    lower = np.flatnonzero(m.particle_body == low_body)
    lower_tris = m.tri_indices[m.tri_body == low_body]
    hx = sim.tool.rounded_box()[0]
    first, under, inverted, tip_inside = None, {}, [], 0
    for k, (pose, twist) in enumerate(experiment_a(sim.tool, sim.params.dt).steps(sim.params.dt), start=1):
        rep = sim.step(pose, twist)
        assert not rep.diverged and np.isfinite(sim.state.particle_q).all()
        x = sim.state.particle_q
        tip = np.array([pose.x + hx * math.cos(pose.yaw), pose.y + hx * math.sin(pose.yaw)])
        tip_inside += point_in_triangles(x, lower_tris, tip)
        inverted.append(rep.n_inverted)
        if first is None and rep.in_contact[low_body]:
            first = k
        if k in (200, 225, 250, 275, 300):
            near = lower[np.linalg.norm(m.particle_q0[lower] - tip, axis=1) < 0.1]
            under[k] = float(np.linalg.norm(x[near] - m.particle_q0[near], axis=1).max())
    # measured: first contact at step 194 (particles only: 272), no inverted triangle, tip never inside
    assert first is not None and 185 <= first <= 200
    assert tip_inside == 0
    assert max(inverted) == 0
    values = [under[k] for k in sorted(under)]
    assert all(b > a for a, b in zip(values, values[1:]))  # pushed deeper and deeper through steps 200-300
    assert values[-1] > 0.05


def test_gather_surface_edges_matches_naive():
    rng = np.random.default_rng(2)
    edges = C.boundary_edges_ccw(mesh_rectangle(1.0, 0.3, 0.1).triangles)
    n_p = int(edges.max()) + 1
    for _ in range(20):
        inv_mass = rng.choice([0.0, 1.0], size=n_p, p=[0.3, 0.7])
        sel = rng.choice(len(edges), size=rng.integers(0, 8), replace=False).astype(np.int32)
        cand0 = np.sort(rng.choice(n_p, size=rng.integers(0, 6), replace=False)).astype(np.int32)
        cand = np.zeros(n_p + 1, np.int32)
        cand[:len(cand0)] = cand0
        mark = np.zeros(n_p, dtype=bool)
        out = np.empty((len(edges), 2), np.int32)
        n = K.gather_surface_edges(edges, sel, len(sel), inv_mass, cand, len(cand0), mark, out)
        e_ref, c_ref = naive.gather_surface_edges(edges, sel, inv_mass, cand0)
        np.testing.assert_array_equal(out[:len(sel)], e_ref.reshape(-1, 2))
        np.testing.assert_array_equal(cand[:n], c_ref)
        assert not mark.any()
