"""Tool-tissue contact: python-fcl queries, the paper's eq. (3), swept projection, reaction.

Kernels are compared with the NumPy references in ``naive.py``; the contact
models are checked against the paper's equation computed by hand, and in
simulations (no tool vs far tool, fast tools, two bodies, reaction force).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.contact import collision as C
from tissue_sim_ros.core.contact import kernels as K
from tissue_sim_ros.core.contact.tool import ToolPose, ToolShape, ToolTwist, tool_shape_array
from tissue_sim_ros.core.mesh import mesh_from_arrays, mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.sim.simulation import Simulation

import naive

BOX = ToolShape("box", length=0.8, width=0.005)
SHAPES = [BOX, ToolShape("capsule", length=0.3, radius=0.004), ToolShape("sphere", radius=0.02),
          ToolShape("capsule", length=0.0, radius=0.01)]


def strip_model(params: SimParams | None = None, width=1.0, height=0.3, spacing=0.05, origin=(0.0, 0.0)) -> Model:
    return Model.from_mesh(mesh_rectangle(width, height, spacing, origin), params or SimParams())


def two_strips(params: SimParams | None = None, gap=0.1) -> Model:
    """Two 1 m x 0.2 m strips, the upper one ``gap`` above the lower one (two bodies).

    The upper strip hangs from its left and right ends (pinned).
    """
    lower = mesh_rectangle(1.0, 0.2, 0.05)
    upper = mesh_rectangle(1.0, 0.2, 0.05, origin=(0.0, 0.2 + gap))
    v = np.vstack([lower.vertices, upper.vertices])
    t = np.vstack([lower.triangles, upper.triangles + len(lower.vertices)])
    ends = (v[:, 1] > 0.2 + gap / 2) & ((v[:, 0] == 0.0) | (v[:, 0] == 1.0))
    return Model.from_mesh(mesh_from_arrays(v, t), params or SimParams(), pinned=ends)


def random_shape(rng: np.random.Generator, tool: ToolShape, margin: float, centre=(0.0, 0.0), spread=0.05):
    pose = ToolPose(centre[0] + rng.uniform(-spread, spread), centre[1] + rng.uniform(-spread, spread),
                    rng.uniform(-math.pi, math.pi))
    return tool_shape_array(tool, pose, margin)


# --------------------------------------------------------------------------- kernels vs NumPy


@pytest.mark.parametrize("tool", SHAPES, ids=lambda t: f"{t.kind}{t.length}")
@pytest.mark.parametrize("move", [0.0, 0.003, 0.05, 0.5])
def test_project_tool_matches_naive(tool, move):
    rng = np.random.default_rng(7)
    for trial in range(6):
        margin = rng.choice([0.0, 0.002])
        s0 = random_shape(rng, tool, margin, spread=0.0)
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        pose1 = ToolPose(s0[0] + move * direction[0], s0[1] + move * direction[1],
                         math.atan2(s0[3], s0[2]) + rng.uniform(-0.2, 0.2) * (trial % 2))
        s1 = tool_shape_array(tool, pose1, margin)
        reach = max(tool.length, tool.radius * 4, 0.02) + move
        n = 40
        x_start = rng.uniform(-reach, reach, size=(n, 2))
        x = x_start + rng.normal(scale=0.01, size=(n, 2))
        inv_mass = np.where(rng.random(n) < 0.1, 0.0, 1e4)
        cand = np.arange(n, dtype=np.int32)
        x_k, acc_k = x.copy(), np.zeros_like(x)
        moved = K.project_tool(x_k, x_start, inv_mass, cand, s0, s1, acc_k)
        x_n, acc_n, moved_n = naive.project_tool(x, x_start, inv_mass, cand, s0, s1)
        np.testing.assert_allclose(x_k, x_n, atol=1e-7)
        np.testing.assert_allclose(acc_k, acc_n, atol=1e-7)
        assert moved == moved_n
        # after the projection no free particle is inside the end shape
        assert (naive.rounded_box_sdf(x_k[inv_mass > 0], s1) >= -1e-9).all()
        # pinned ones never move
        np.testing.assert_array_equal(x_k[inv_mass == 0], x[inv_mass == 0])


def test_project_tool_degenerate_inputs():
    cand = np.zeros(1, dtype=np.int32)
    w = np.ones(1)
    # a particle exactly at the centre of a box (yaw 0): out through the +y face (ties go to y)
    s = tool_shape_array(BOX, ToolPose(0.3, 0.2, 0.0), 0.001)
    x = np.array([[0.3, 0.2]])
    acc = np.zeros((1, 2))
    assert K.project_tool(x, x.copy(), w, cand, s, s, acc) == 1
    np.testing.assert_allclose(x, [[0.3, 0.2 + 0.0025 + 0.001]], atol=1e-15)
    np.testing.assert_allclose(acc, [[0.0, 0.0035]], atol=1e-15)
    # the same at yaw pi: the tool's +y is world -y
    s = tool_shape_array(BOX, ToolPose(0.3, 0.2, math.pi), 0.001)
    x = np.array([[0.3, 0.2]])
    K.project_tool(x, x.copy(), w, cand, s, s, np.zeros((1, 2)))
    np.testing.assert_allclose(x, [[0.3, 0.2 - 0.0035]], atol=1e-12)
    # a zero-length capsule is a disc: a particle at its centre goes out by the radius
    cap = ToolShape("capsule", length=0.0, radius=0.01)
    s = tool_shape_array(cap, ToolPose(0.0, 0.0, 0.0), 0.0)
    x = np.zeros((1, 2))
    K.project_tool(x, x.copy(), w, cand, s, s, np.zeros((1, 2)))
    assert math.isclose(float(np.hypot(*x[0])), 0.01, rel_tol=1e-12)
    # a zero-length capsule sweeping over a particle pushes it ahead, not through
    s0 = tool_shape_array(cap, ToolPose(-0.05, 0.0, 0.0), 0.0)
    s1 = tool_shape_array(cap, ToolPose(0.5, 0.0, 0.0), 0.0)
    x = np.zeros((1, 2))
    K.project_tool(x, x.copy(), w, cand, s0, s1, np.zeros((1, 2)))
    np.testing.assert_allclose(x, [[0.51, 0.0]], atol=1e-12)
    # a particle resting on the surface of a still tool is not moved
    s = tool_shape_array(BOX, ToolPose(0.0, 0.0, 0.0), 0.0)
    x = np.array([[0.1, 0.0025]])
    acc = np.zeros((1, 2))
    assert K.project_tool(x, x.copy(), w, cand, s, s, acc) == 0
    assert not acc.any()
    # a pinned particle inside is left alone
    x = np.array([[0.0, 0.0]])
    assert K.project_tool(x, x.copy(), np.zeros(1), cand, s, s, np.zeros((1, 2))) == 0
    np.testing.assert_array_equal(x, [[0.0, 0.0]])


@pytest.mark.parametrize("factor", [10, 100])
def test_project_tool_fast_tool_cannot_tunnel(factor):
    """A box moving factor x its width in one step pushes a row of particles ahead of it."""
    move = factor * BOX.width
    s0 = tool_shape_array(BOX, ToolPose(0.5, 0.5, 0.0), 0.001)
    s1 = tool_shape_array(BOX, ToolPose(0.5, 0.5 - move, 0.0), 0.001)
    xs = np.linspace(0.15, 0.85, 15)
    x_start = np.stack([xs, np.full_like(xs, 0.49)], axis=1)  # 7 mm below the tool
    x = x_start.copy()
    acc = np.zeros_like(x)
    moved = K.project_tool(x, x_start, np.ones(len(xs)), np.arange(len(xs), dtype=np.int32), s0, s1, acc)
    assert moved == len(xs)
    np.testing.assert_allclose(x[:, 1], 0.5 - move - 0.0025 - 0.001, atol=1e-12)  # below the tool, on its surface
    np.testing.assert_allclose(x[:, 0], xs)
    # a particle beyond the tool's end is not touched
    x = np.array([[0.95, 0.49]])
    assert K.project_tool(x, x.copy(), np.ones(1), np.zeros(1, np.int32), s0, s1, np.zeros((1, 2))) == 0


def test_points_sdf_near_and_compact_match_naive():
    rng = np.random.default_rng(3)
    model = strip_model()
    x = model.particle_q0 + rng.normal(scale=0.005, size=model.particle_q0.shape)
    tris = np.ascontiguousarray(model.tri_indices)
    for tool in SHAPES:
        for _ in range(10):
            s = random_shape(rng, tool, 0.0, centre=(0.5, 0.32), spread=0.1)
            sdf, grad = np.empty(len(x)), np.empty((len(x), 2))
            K.points_sdf(x, s, sdf, grad)
            np.testing.assert_allclose(sdf, naive.rounded_box_sdf(x, s), atol=1e-12)
            reach = rng.uniform(0.0, 0.05)
            out = np.empty(len(tris), dtype=np.int32)
            n = K.near_triangles(x, tris, sdf, grad, reach, out)
            np.testing.assert_array_equal(out[:n], naive.near_triangles(x, tris, sdf, grad, reach))
            # conservative: every triangle with a sampled point within reach is kept
            bary = rng.dirichlet(np.ones(3), size=64)
            for t in range(len(tris)):
                pts = bary @ x[tris[t]]
                if naive.rounded_box_sdf(pts, s).min() <= reach:
                    assert t in out[:n]
            if n:
                vmap = np.full(len(x), -1, dtype=np.int32)
                verts, ids, ctris = np.empty((len(x), 3)), np.empty(len(x), np.int32), np.empty((n, 3), np.int32)
                nv = K.compact_triangles(x, tris, out, n, vmap, verts, ids, ctris)
                v_ref, ids_ref, t_ref = naive.compact_triangles(x, tris, out[:n])
                np.testing.assert_array_equal(ids[:nv], ids_ref)
                np.testing.assert_array_equal(ctris, t_ref)
                np.testing.assert_array_equal(verts[:nv], v_ref)
                assert (vmap == -1).all()


def test_swept_candidates_match_naive_and_cover_the_sweep():
    rng = np.random.default_rng(5)
    model = strip_model()
    x = np.ascontiguousarray(model.particle_q0)
    inv_mass = np.where(rng.random(len(x)) < 0.1, 0.0, 1e4)
    for tool in SHAPES:
        for _ in range(8):
            s0 = random_shape(rng, tool, 0.002, centre=(0.5, 0.3), spread=0.2)
            s1 = random_shape(rng, tool, 0.002, centre=(0.5, 0.3), spread=0.2)
            reach = rng.uniform(0.0, 0.02)
            out = np.empty(len(x), dtype=np.int32)
            n = K.swept_candidates(x, inv_mass, s0, s1, reach, out)
            np.testing.assert_array_equal(out[:n], naive.swept_candidates(x, inv_mass, s0, s1, reach))
            # every free particle within reach of the tool at an intermediate pose is a candidate
            a0, a1 = math.atan2(s0[3], s0[2]), math.atan2(s1[3], s1[2])
            da = math.atan2(math.sin(a1 - a0), math.cos(a1 - a0))
            for f in np.linspace(0.0, 1.0, 21):
                pose = ToolPose(s0[0] + f * (s1[0] - s0[0]), s0[1] + f * (s1[1] - s0[1]), a0 + f * da)
                d = naive.rounded_box_sdf(x, tool_shape_array(tool, pose, 0.002))
                assert set(np.flatnonzero((d <= reach) & (inv_mass > 0))) <= set(out[:n])


def test_paper_displacement_matches_naive():
    rng = np.random.default_rng(13)
    for trial in range(20):
        n = 80
        x = rng.uniform(0, 1, size=(n, 2))
        inv_mass = np.where(rng.random(n) < 0.2, 0.0, 1e4)
        parts = np.sort(rng.choice(n, size=50, replace=False)).astype(np.int32)
        q = int(parts[trial % 50])
        d_star = [0.0, 0.01, 0.024][trial % 3]
        v = rng.normal(size=2)
        u = v / np.hypot(*v)
        r = 0.25
        if trial == 0:
            x[parts[1]] = x[q] + np.array([r, 0.0])  # exactly at r: displaced by zero, still in the set
        out_idx, out_dx = np.empty(n, np.int32), np.empty((n, 2))
        k = K.paper_displacement(x, parts, inv_mass, q, d_star, u[0], u[1], r, out_idx, out_dx)
        free = parts[inv_mass[parts] > 0]
        idx_ref, dx_ref = naive.paper_displacement(x, free, q, d_star, v, r)
        np.testing.assert_array_equal(out_idx[:k], idx_ref)
        np.testing.assert_allclose(out_dx[:k], dx_ref, atol=1e-15)
        if trial == 0 and inv_mass[parts[1]] > 0:
            assert parts[1] in out_idx[:k]


def test_body_nearest_matches_naive():
    rng = np.random.default_rng(17)
    for n_bodies in (1, 3):
        body = rng.integers(0, n_bodies, size=50).astype(np.int32)
        sdf = rng.choice([-0.01, 0.0, 0.003, 0.5], size=50)  # ties on purpose
        out_min, out_arg = np.empty(n_bodies + 1), np.empty(n_bodies + 1, dtype=np.int32)  # last body empty
        K.body_nearest(sdf, body, out_min, out_arg)
        ref_min, ref_arg = naive.body_nearest(sdf, body, n_bodies + 1)
        np.testing.assert_array_equal(out_min, ref_min)
        np.testing.assert_array_equal(out_arg, ref_arg)


# --------------------------------------------------------------------------- python-fcl queries


@pytest.mark.parametrize("tool", SHAPES, ids=lambda t: f"{t.kind}{t.length}")
def test_fcl_distance_and_q_match_a_dense_numpy_search(tool):
    """d* from fcl equals the exact mesh-tool distance; q is a vertex of the nearest triangle; culling changes nothing."""
    rng = np.random.default_rng(11)
    model = strip_model()
    x = model.particle_q0 + rng.normal(scale=0.004, size=model.particle_q0.shape)
    state = model.state()
    state.particle_q[:] = x
    full = C.ContactModel(model, tool, cull=False)
    culled = C.ContactModel(model, tool)
    bary = rng.dirichlet(np.ones(3), size=400)
    pts = np.einsum("kj,tjd->tkd", bary, x[model.tri_indices])  # (T, 400, 2) points of every triangle
    checked = 0
    for _ in range(25):
        pose = ToolPose(rng.uniform(0.2, 0.8), 0.3 + rng.uniform(0.006, 0.03) + 0.02 * (tool.kind == "sphere"),
                        rng.uniform(-0.3, 0.3))
        shape = tool_shape_array(tool, pose)
        sdf_all = naive.rounded_box_sdf(pts.reshape(-1, 2), shape).reshape(pts.shape[:2])
        exact = sdf_all.min()
        twist = ToolTwist(0.0, -0.1)
        c_full = full.detect(state, pose, pose, twist, 0.01)
        c_cull = culled.detect(state, pose, pose, twist, 0.01)
        if exact <= 0:
            continue
        # dense sampling overestimates the distance by a little
        assert c_full.d_star[0] <= exact + 1e-9
        assert c_full.d_star[0] >= exact - 2e-3
        if c_full.d_star[0] < 0.025:
            checked += 1
            assert c_cull.d_star[0] == pytest.approx(c_full.d_star[0], abs=1e-12)
            res = culled.distances(x, pose, 0.025)[0]
            # q is a vertex of a triangle holding the nearest point: the nearest of that triangle's vertices
            tri_of_q = [t for t in model.tri_indices if res.q in t]
            assert any(np.isclose(naive.rounded_box_sdf(pts[k], shape).min(), exact, atol=2e-3)
                       for k, t in enumerate(model.tri_indices) if res.q in t), tri_of_q
        else:
            assert math.isinf(c_cull.d_star[0])
    assert checked >= 5


def test_overlap_is_contact_at_distance_zero_with_the_deepest_particle_as_q():
    model = strip_model()
    cm = C.ContactModel(model, BOX)
    state = model.state()
    pose = ToolPose(0.5, 0.299, 0.0)  # the box's lower face 1.5 mm inside the strip's top row
    c = cm.detect(state, pose, pose, ToolTwist(0.0, -0.1), 0.01)
    assert c.in_contact[0] and c.d_star[0] == 0.0
    assert len(c.held_idx) == 0  # eq. (3) with d* = 0 displaces nothing, so nothing is held
    res = cm.distances(state.particle_q, pose, 0.025)[0]
    assert res.overlap
    # a thin tool between vertices (no vertex inside): python-fcl reports -1, handled the same way
    tool = ToolShape("box", length=0.04, width=0.002)
    cm = C.ContactModel(model, tool)
    pose = ToolPose(0.5, 0.275, 0.0)
    sdf = naive.rounded_box_sdf(state.particle_q, tool_shape_array(tool, pose))
    assert sdf.min() > 0
    res = cm.distances(state.particle_q, pose, 0.025)[0]
    assert res.overlap and res.d_star == 0.0 and res.n_tris > 0
    assert res.q == int(np.argmin(sdf))


# --------------------------------------------------------------------------- the paper's eq. (3)


def test_approach_at_authors_speed_matches_eq3_by_hand():
    """A horizontal box descending at 0.001 m per step onto a strip (top at y = 0.3).

    d* = (tool y - width/2) - 0.3; contact starts at the first step where d* < alpha,
    and the displaced particles and displacements are eq. (3) computed here by hand.
    """
    p = SimParams()
    model = strip_model(p)
    cm = C.ContactModel(model, BOX)
    state = model.state()
    x = state.particle_q
    y0, dy, dt = 0.36, 0.001, p.dt
    first = None
    for k in range(1, 60):
        pose0, pose1 = ToolPose(0.5, y0 - (k - 1) * dy, 0.0), ToolPose(0.5, y0 - k * dy, 0.0)
        twist = ToolTwist(0.0, -dy / dt)
        c = cm.detect(state, pose0, pose1, twist, dt)
        d_hand = pose1.y - 0.5 * BOX.width - 0.3
        if d_hand < p.contact_threshold:
            assert c.d_star[0] == pytest.approx(max(d_hand, 0.0), abs=1e-9)  # overlap: d* = 0
        if c.in_contact[0] and first is None:
            first = k
            # eq. (3) by hand around the q the model chose: q is on the top row, nearest to the tool
            q = c.touched[np.argmax(np.abs(c.held_dx[:, 1]))]
            assert x[q, 1] == pytest.approx(0.3)
            dist = np.hypot(*(x - x[q]).T)
            expect = np.flatnonzero(dist <= p.contact_radius)
            np.testing.assert_array_equal(np.sort(c.held_idx), expect)
            mag = (p.contact_radius - dist[c.held_idx]) / p.contact_radius * d_hand
            np.testing.assert_allclose(c.held_dx[:, 0], 0.0, atol=1e-15)
            np.testing.assert_allclose(c.held_dx[:, 1], -mag, rtol=1e-9, atol=1e-15)
            idx_ref, dx_ref = naive.paper_displacement(x, np.arange(model.n_particles), q, d_hand, (0.0, -dy / dt),
                                                       p.contact_radius)
            np.testing.assert_array_equal(np.sort(c.held_idx), np.sort(idx_ref))
            assert np.abs(c.held_dx[:, 1]).max() == pytest.approx(d_hand, rel=1e-9)  # q itself moves by d*
    # the first step with d* < alpha: 0.36 - k 0.001 - 0.0025 - 0.3 < 0.025 -> k = 33
    expected = next(k for k in range(1, 60) if y0 - k * dy - 0.0025 - 0.3 < p.contact_threshold)
    assert first == expected == 33


def test_tool_at_rest_or_far_moves_nothing():
    model = strip_model()
    cm = C.ContactModel(model, BOX)
    state = model.state()
    pose = ToolPose(0.5, 0.31, 0.0)
    c = cm.detect(state, pose, pose, ToolTwist(0.0, 0.0, 0.5), 0.01)  # rotating in place, |v| = 0
    assert c.in_contact[0] and len(c.held_idx) == 0
    far = ToolPose(0.5, 2.0, 0.0)
    c = cm.detect(state, far, far, ToolTwist(0.0, -1.0), 0.01)
    assert not c.in_contact.any() and len(c.held_idx) == 0 and math.isinf(c.d_star[0])


def test_pinned_particles_are_not_displaced():
    model = Model.from_mesh(mesh_rectangle(1.0, 0.3, 0.05), SimParams(), pinned=np.arange(21, 63))
    cm = C.ContactModel(model, BOX)
    pose = ToolPose(0.5, 0.31, 0.0)
    c = cm.detect(model.state(), pose, pose, ToolTwist(0.0, -0.1), 0.01)
    assert len(c.held_idx) > 0
    assert not model.particle_pinned[c.held_idx].any()


def test_two_bodies_detection_never_mixes_them():
    """The tool 5 mm above the upper strip: r = 0.25 reaches the lower strip, which must not move."""
    model = two_strips()
    cm = C.ContactModel(model, BOX)
    top = 0.2 + 0.1 + 0.2
    pose = ToolPose(0.5, top + 0.005 + 0.0025, 0.0)
    c = cm.detect(model.state(), pose, pose, ToolTwist(0.0, -0.1), 0.01)
    upper = model.particle_body[np.argmax(model.particle_q0[:, 1])]
    assert c.in_contact[upper] and not c.in_contact[1 - upper]
    assert (model.particle_body[c.held_idx] == upper).all()
    q_y = model.particle_q0[c.held_idx, 1].max()
    assert q_y == pytest.approx(top)
    # a tool in a 3 cm gap between two strips touches both: each body is displaced around its own q only
    model = two_strips(gap=0.03)
    cm = C.ContactModel(model, BOX)
    pose = ToolPose(0.5, 0.215, 0.0)
    c = cm.detect(model.state(), pose, pose, ToolTwist(0.0, -0.1), 0.01)
    assert c.in_contact.all()
    np.testing.assert_allclose(c.d_star, 0.015 - 0.0025, atol=1e-12)
    x = model.particle_q0
    for b in range(2):
        idx = c.held_idx[model.particle_body[c.held_idx] == b]
        dx = c.held_dx[model.particle_body[c.held_idx] == b]
        assert len(idx) > 0
        # its own q: the particle moved by the full d*, on this body's face next to the tool
        q = idx[np.argmax(np.abs(dx[:, 1]))]
        assert x[q, 1] == pytest.approx(0.2 if b == model.particle_body[0] else 0.23)
        assert (np.hypot(*(x[idx] - x[q]).T) <= 0.25).all()


# --------------------------------------------------------------------------- in the simulation


def _run(model: Model, tool: ToolShape | None, poses, steps: int):
    sim = Simulation(model, tool)
    reports = [sim.step(poses(k) if tool is not None else None) for k in range(1, steps + 1)]
    return sim, reports


@pytest.mark.parametrize("kind", ["paper", "projection"])
def test_far_tool_changes_nothing(kind):
    p = SimParams(contact_model=kind, boundary_y_bottom=0.001)
    model = strip_model(p)
    sim_free, rep_free = _run(model, None, None, 20)
    sim_tool, rep_tool = _run(model, BOX, lambda k: ToolPose(0.5, 1.5 - 0.001 * k, 0.0), 20)
    np.testing.assert_array_equal(sim_tool.state.particle_q, sim_free.state.particle_q)
    for a, b in zip(rep_free, rep_tool):
        assert a.energy.scene_total == b.energy.scene_total
        assert not b.in_contact.any() and b.n_contact_particles == 0
        np.testing.assert_array_equal(b.reaction_force, 0.0)
        assert b.reaction_torque == 0.0


@pytest.mark.parametrize("factor", [10, 100])
def test_fast_tool_crossing_a_strip(factor):
    """A box crossing a 0.3 m strip from above at factor x its width per step.

    projection: no particle ends a step inside the tool, and the tissue under
    the tool is pushed down, not tunnelled. paper: the documented failure, recorded.
    """
    move = factor * BOX.width
    strip = dict(width=1.0, height=0.3, spacing=0.05, origin=(0.0, 0.5))
    results = {}
    for kind in ("projection", "paper"):
        p = SimParams(contact_model=kind, boundary_y_bottom=0.501)
        model = strip_model(p, **strip)
        sim = Simulation(model, BOX)
        y_start = 0.8 + 0.02
        n_steps = int(math.ceil(0.25 / move)) + 1  # down to ~y 0.57: inside the strip, above its pinned bottom
        top_row = np.flatnonzero(np.isclose(model.particle_q0[:, 1], 0.8) & (np.abs(model.particle_q0[:, 0] - 0.5) < 0.3))
        inside = []
        for k in range(n_steps + 1):
            y = max(y_start - k * move, 0.57)
            pose = ToolPose(0.5, y, 0.0)
            rep = sim.step(pose)
            assert not rep.diverged
            sdf = naive.rounded_box_sdf(sim.state.particle_q, tool_shape_array(BOX, pose, 0.0))
            inside.append(int(np.sum(sdf < -1e-9)))
        below = sim.state.particle_q[top_row, 1] < y - 0.0025
        above = sim.state.particle_q[top_row, 1] > y + 0.0025
        results[kind] = (inside, below, above)
    inside, below, above = results["projection"]
    assert max(inside) == 0
    assert below.all()  # the top row under the tool was carried down with it
    inside, below, above = results["paper"]
    # the paper's rule (recorded): the first step that reaches the tissue already overlaps it
    # (the tool moves >= 2 alpha per step), so d* = 0, eq. (3) displaces nothing and the tool
    # passes through: the whole top row under the tool ends above it, the tool ~0.23 m deep
    # in the tissue. (No particle happens to end inside this 5 mm box: the mesh is 5 cm.)
    assert above.all()
    print(f"paper model at {factor}x: particles inside the tool per step {inside}")


def test_two_bodies_contact_with_the_upper_never_moves_the_lower():
    for kind in ("paper", "projection"):
        p = SimParams(contact_model=kind, boundary_y_bottom=0.001)
        model = two_strips(p)
        lower = model.particle_body == model.particle_body[np.argmin(model.particle_q0[:, 1])]
        free_sim, _ = _run(model, None, None, 30)
        sim, reports = _run(model, BOX, lambda k: ToolPose(0.5, 0.52 - 0.002 * k, 0.0), 30)
        assert any(r.in_contact.any() for r in reports)
        np.testing.assert_array_equal(sim.state.particle_q[lower], free_sim.state.particle_q[lower])
        assert not np.array_equal(sim.state.particle_q[~lower], free_sim.state.particle_q[~lower])


def test_reaction_force_projection():
    """Zero without contact; opposite to the tool's push; growing with indentation."""
    p = SimParams(contact_model="projection", boundary_y_bottom=0.001)
    model = strip_model(p)
    sim = Simulation(model, BOX)
    forces = []
    for k in range(1, 41):
        rep = sim.step(ToolPose(0.5, 0.32 - 0.001 * k, 0.0))
        forces.append(rep.reaction_force.copy())
        if not rep.in_contact.any():
            np.testing.assert_array_equal(rep.reaction_force, 0.0)
    f = np.array(forces)
    pushing = f[:, 1] > 0  # the tool pushes down (-y): the tissue pushes back up
    assert pushing[-10:].all()
    assert np.all(np.abs(f[-10:, 0]) < 0.2 * f[-10:, 1])
    # growing with indentation: the last steps push back harder than the first steps of contact
    first = int(np.argmax(pushing))
    assert f[-5:, 1].mean() > 2.0 * f[first:first + 5, 1].mean()


def test_reaction_force_paper():
    """The paper model's reaction is -m held_dx / dt^2: opposite to the tool's motion, zero without contact."""
    p = SimParams(contact_model="paper", boundary_y_bottom=0.001)
    model = strip_model(p)
    sim = Simulation(model, BOX)
    seen = False
    for k in range(1, 41):
        rep = sim.step(ToolPose(0.5, 0.35 - 0.001 * k, 0.0))
        assert rep.in_contact[0] == (rep.d_star[0] < p.contact_threshold)  # contact starts when d* < alpha
        if rep.n_contact_particles == 0:
            np.testing.assert_array_equal(rep.reaction_force, 0.0)
        elif rep.d_star[0] > 0.0:
            seen = True
            assert rep.reaction_force[1] > 0.0
            assert abs(rep.reaction_force[0]) < 1e-9 * rep.reaction_force[1]
        else:
            np.testing.assert_array_equal(rep.reaction_force, 0.0)  # overlap: d* = 0, nothing displaced
    assert seen


def test_project_tool_rotating_tool_sweeps_particles_aside():
    """A box turning 0.2 rad in one step about its centre: particles its arm sweeps over stay on their side."""
    s0 = tool_shape_array(BOX, ToolPose(0.0, 0.0, 0.0), 0.001)
    s1 = tool_shape_array(BOX, ToolPose(0.0, 0.0, 0.2), 0.001)
    radii = np.linspace(0.05, 0.39, 12)
    x_start = np.stack([radii * np.cos(0.1), radii * np.sin(0.1)], axis=1)  # halfway through the sweep
    x = x_start.copy()
    acc = np.zeros_like(x)
    moved = K.project_tool(x, x_start, np.ones(len(radii)), np.arange(len(radii), dtype=np.int32), s0, s1, acc)
    assert moved == len(radii)
    local = naive.tool_local(x, s1)
    np.testing.assert_allclose(local[:, 1], 0.0025 + 0.001, atol=1e-12)  # pushed ahead, on the +y face that swept into them
    x_ref, acc_ref, moved_ref = naive.project_tool(x_start, x_start, np.ones(len(radii)),
                                                   np.arange(len(radii)), s0, s1)
    np.testing.assert_allclose(x, x_ref, atol=1e-7)


@pytest.mark.parametrize("kind", ["paper", "projection"])
def test_reaction_torque_about_the_tool_centre(kind):
    """A tilted box whose tip (right of its centre) presses down: the push-back is up, so the torque is > 0."""
    p = SimParams(contact_model=kind, boundary_y_bottom=0.001)
    model = strip_model(p)
    sim = Simulation(model, BOX)
    yaw = -0.3
    torques = []
    for k in range(1, 61):
        tip = (0.7, 0.32 - 0.001 * k)
        pose = ToolPose(tip[0] - 0.4 * math.cos(yaw), tip[1] - 0.4 * math.sin(yaw), yaw)
        rep = sim.step(pose)
        if np.any(rep.reaction_force != 0.0):
            torques.append((rep.reaction_force[1], rep.reaction_torque))
            if kind == "paper":
                assert rep.reaction_force[1] > 0.0  # eq. (3) pushes along v (down): the reaction is up
    # once the lower face presses: up, right of the centre. (Before that, with projection, the
    # strip's corner slides over the tip's end face, whose push passes nearly through the centre.)
    assert len(torques) >= 10
    assert all(fy > 0.0 and t > 0.0 for fy, t in torques[-10:])


def test_contact_bench_quick_writes_table_csv_and_chart(tmp_path, capsys):
    """Smoke test of ``tissue-sim bench contact --quick --only detection`` (no timing is asserted; the force
    smoothness part has its own, test/test_bench_contact.py)."""
    from tissue_sim_ros.cli import main

    assert main(["bench", "contact", "--quick", "--only", "detection", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "culled" in out and "full" in out
    rows = (tmp_path / "contact.csv").read_text().splitlines()
    assert rows[0].startswith("scene,contact_model,bvh") and len(rows) == 5
    assert (tmp_path / "contact.png").stat().st_size > 0
    assert main(["bench", "contact", "--steps", "0", "--out", str(tmp_path)]) == 2
