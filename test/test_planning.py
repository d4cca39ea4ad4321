"""core/plan/insertion.py without ROS: locating the target, the request's checks, the sweep's candidates."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.contact.collision import ContactModel
from tissue_sim_ros.core.contact.kernels import points_sdf
from tissue_sim_ros.core.contact.tool import StraightInsertion, tool_shape_array
from tissue_sim_ros.core.plan.insertion import InsertionRequest, candidates_for, locate, plan_insertion, tool_overlaps
from tissue_sim_ros.core.sim.batch import BatchScene
from tissue_sim_ros.core.sim.scene import build_simulation

TARGET = (0.55, 0.38)
A = math.radians(-30.0)
ENTRY = (TARGET[0] - 0.12 * math.cos(A), TARGET[1] - 0.12 * math.sin(A))


@pytest.fixture(scope="module")
def scene():
    sim = build_simulation({"tool_length": 0.3, "contact_model": "projection"})
    return sim, BatchScene.from_simulation(sim)


def test_locate_gives_the_triangle_and_barycentric_coordinates():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    tris = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32)
    t, bary = locate(x, tris, (0.75, 0.5))
    assert t == 1 and np.allclose(bary @ x[tris[t]], [0.75, 0.5]) and (bary >= 0).all()
    assert np.isclose(bary.sum(), 1.0)
    assert locate(x, tris, (1.5, 0.5)) is None
    assert locate(x, tris, (0.5, 0.5))[0] == 0  # on the shared edge: the lowest index
    assert locate(x, np.zeros((0, 3), np.int32), (0.5, 0.5)) is None


@pytest.mark.parametrize("entry,target,tol,match", [
    (ENTRY, (0.5, 0.5), 0.01, "outside the tissue"),
    ((0.5, 0.2), TARGET, 0.01, "inside the tissue"),
    (TARGET, TARGET, 0.01, "same point"),
    (ENTRY, TARGET, 0.0, "expected > 0"),
    ((math.nan, 0.4), TARGET, 0.01, "NaN/inf"),
])
def test_requests_that_cannot_be_planned_say_why(scene, entry, target, tol, match):
    sim, sc = scene
    plan = plan_insertion(sim.snapshot(), sc, InsertionRequest(entry, target, tol))
    assert not plan.ok and match in plan.reason and plan.batch is None


def test_candidates_too_long_or_overlapping_are_not_rolled_out(scene):
    sim, sc = scene
    req = InsertionRequest(ENTRY, TARGET, 0.01, angle_offsets_deg=(0.0, -50.0), speeds=(0.1, 0.01), max_steps=200)
    cands = candidates_for(sc, sim.snapshot(), req)
    by = {(c.angle_offset_deg, c.speed): c for c in cands}
    assert by[(0.0, 0.1)].path is not None and by[(0.0, 0.1)].path.n_steps == 120
    assert "more than plan_max_steps=200" in by[(0.0, 0.01)].reason  # 0.12 m at 0.01 m/s: 1200 steps
    # -80 deg: the 0.3 m tool stands up into the upper tissue at its entry
    assert "overlaps the tissue" in by[(-50.0, 0.1)].reason


def _samples_inside(x, tris, tool, pose, n=801):
    """Independent reference: points of the tool's rectangle (axis and both long sides, n along) inside a triangle."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    count = 0
    for u in np.linspace(-tool.length / 2, tool.length / 2, n):
        for v in (-tool.width / 2, 0.0, tool.width / 2):
            count += locate(x, tris, (pose.x + u * c - v * s, pose.y + u * s + v * c)) is not None
    return count


def test_a_thin_tool_lying_across_the_tissue_overlaps_it():
    """The 0.8 m x 5 mm tool of the shipped scene, at the entries of the README's request: python-fcl's overlap
    agrees with sampling the tool's rectangle for triangles, including entries where no particle lies inside the
    tool (the particle test alone let those through, and such a plan cost 0)."""
    sim = build_simulation({})
    x, tris = sim.snapshot().particle_q, sim.model.tri_indices
    contact = ContactModel(sim.model, sim.tool)
    entry, target = (0.377, 0.48), (0.55, 0.38)
    base, dist = math.atan2(target[1] - entry[1], target[0] - entry[0]), math.hypot(0.173, 0.1)
    sdf, grad = np.empty(x.shape[0]), np.empty((x.shape[0], 2))
    thin_only = 0
    for off in (-30.0, -10.0, 10.0, 20.0, 30.0, 40.0):
        a = base + math.radians(off)
        start = StraightInsertion.from_tool(sim.tool, (target[0] - dist * math.cos(a), target[1] - dist * math.sin(a)),
                                            target, 0.1).pose_at(0.0)
        inside = _samples_inside(x, tris, sim.tool, start)
        assert tool_overlaps(contact, x, start) == (inside > 0), (off, inside)
        points_sdf(x, tool_shape_array(sim.tool, start, 0.0), sdf, grad)
        thin_only += inside > 0 and sdf.min() > 0.0
    assert thin_only >= 1, "some entry should cross triangles with no particle inside the tool"


def test_plan_picks_the_cheapest_feasible_and_tracks_the_target(scene):
    sim, sc = scene
    req = InsertionRequest(ENTRY, TARGET, 0.01, angle_offsets_deg=(-10.0, 0.0, 10.0), speeds=(0.2,))
    plan = plan_insertion(sim.snapshot(), sc, req)
    assert plan.ok and plan.candidates[plan.best].cost == min(c.cost for c in plan.candidates)
    # projection contact pushes the target ahead of the tip by about its depth (16 mm)
    assert all(0.005 < c.target_error < 0.03 for c in plan.candidates)
    tracked = plan_insertion(sim.snapshot(), sc, InsertionRequest(ENTRY, TARGET, 0.001, (0.0,), (0.2,),
                                                                  track_target=True))
    assert not tracked.ok and "no candidate within tolerance 1.0 mm" in tracked.reason
    loose = plan_insertion(sim.snapshot(), sc, InsertionRequest(ENTRY, TARGET, 0.05, (0.0,), (0.2,),
                                                                track_target=True))
    assert loose.ok


def test_the_plan_chart_keeps_its_legend_off_the_curves(tmp_path, monkeypatch):
    """plan.png's legend sat inside the axes and hid a curve: it is drawn beside them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tissue_sim_ros.experiments import plan

    rows = [{"angle_deg": a, "speed_m_per_step": s, "cost": (1e-8 if s == 0.002 else 3e-8) * (1 + (a + 40) / 5)}
            for s in (0.001, 0.002) for a in range(-40, 0, 5)]
    rows.sort(key=lambda r: r["cost"])
    kept = {}
    monkeypatch.setattr(plt, "close", lambda fig: kept.setdefault("fig", fig))
    plan.chart(tmp_path / "plan.png", rows, (0.55, 0.38))
    fig = kept["fig"]
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent(renderer)
    assert not legend.overlaps(ax.get_window_extent(renderer)), (legend, ax.get_window_extent(renderer))
    assert legend.x1 <= fig.bbox.x1 + 1  # and inside the picture
