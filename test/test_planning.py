"""core/planning.py without ROS: locating the target, the request's checks, the sweep's candidates."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.batch import BatchScene
from tissue_sim_ros.core.planning import InsertionRequest, candidates_for, locate, plan_insertion
from tissue_sim_ros.core.scene import build_simulation

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
