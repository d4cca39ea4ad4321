"""``tissue-sim bench contact``'s force smoothness (its quick version): the material's default step (ipc, barrier
contact) against the former default (quasi_newton, projection) under a held and a dragged capsule.

What is checked is physics, never time: under the held tool the default's reaction is steady (the issue's goal:
< 0.5% change between steps, lateral < 1% of the normal of a centred press), nothing inverts or enters the tool,
and a capsule dragged with friction 0.3 feels Fx/Fy = -0.3.
"""
from __future__ import annotations

import csv

import pytest

from tissue_sim_ros.bench import contact
from tissue_sim_ros.cli import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("contact")
    assert main(["bench", "contact", "--quick", "--only", "smoothness", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "contact_smoothness.csv")))
    return out, {(r["method"], r["case"], float(r["friction"])): r for r in rows}


def test_writes_the_table_the_steps_and_the_chart(quick):
    out, rows = quick
    # E 50 kPa: ipc held, dragged at friction 0 and 0.3; the former default held and dragged (no friction)
    assert set(rows) == {("ipc", "hold", 0.0), ("ipc", "drag", 0.0), ("ipc", "drag", 0.3),
                         ("quasi_newton", "hold", 0.0), ("quasi_newton", "drag", 0.0)}
    steps = list(csv.DictReader(open(out / "contact_smoothness_steps.csv")))
    held = [s for s in steps if s["method"] == "ipc" and s["case"] == "hold" and s["measured"] == "True"]
    assert len(held) == 10 == int(rows[("ipc", "hold", 0.0)]["steps"])
    assert (out / "contact_smoothness.png").stat().st_size > 0


def test_the_default_holds_a_steady_force(quick):
    _, rows = quick
    hold = rows[("ipc", "hold", 0.0)]
    assert float(hold["fy_mean_N"]) > 0.5  # pressed a third deep into 50 kPa: the tissue pushes back
    assert float(hold["dfn_median"]) < 5e-3
    assert float(hold["lateral_max"]) < 1e-2  # a centred press on a symmetric mesh
    for key, r in rows.items():
        if key[0] == "ipc":
            assert int(r["inverted_steps"]) == 0 and float(r["penetration_max_m"]) == 0.0, key
            assert 0.0 <= float(r["lag_end_m"]) < 1e-4, key
    # the former default's held force changes far more from step to step
    assert float(rows[("quasi_newton", "hold", 0.0)]["dfn_median"]) > 10 * float(hold["dfn_median"])


def test_friction_drags_with_coulomb_ratio(quick):
    _, rows = quick
    assert abs(float(rows[("ipc", "drag", 0.0)]["fx_over_fy"])) < 0.05
    # dragged to +x: the tissue holds the tool back, Fx = -mu Fy
    assert float(rows[("ipc", "drag", 0.3)]["fx_over_fy"]) == pytest.approx(-0.3, abs=0.05)


def test_poses_press_then_hold_or_drag():
    ps, first, last = contact.smooth_poses("hold", hold=7)
    assert last - first == 7 and ps[-1] == ps[-7] and len(ps) == last
    assert ps[-1].y - contact.CAPSULE_RADIUS == pytest.approx(contact.STRIP_H * 2 / 3)
    ps, first, last = contact.smooth_poses("drag")
    assert ps[-1].x - ps[0].x == pytest.approx(contact.DRAG_DISTANCE)
    assert ps[-1].y - contact.CAPSULE_RADIUS == pytest.approx(contact.STRIP_H - contact.DRAG_DEPTH)
    assert last == len(ps) and (ps[first].x - ps[0].x) == pytest.approx(contact.DRAG_SKIP, abs=2e-4)


def test_bad_part_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:  # argparse's choices
        main(["bench", "contact", "--only", "moon", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "invalid choice: 'moon'" in capsys.readouterr().err
    with pytest.raises(contact.InputError, match="--only='moon'"):  # the library's own check
        contact.run(tmp_path, only="moon")
