"""The paper's experiments, headless and shortened, and the demo end to end through ROS.

Experiment a at reduced length (220 of 300 steps, snapshots 0/150/220) and
experiment b on a shorter insertion; the demo runs the real node, recorder and
tool driver as processes, and its bag is read back with the independent
`mcap` reader.
"""
from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.core.timing import trajectories as tr
from tissue_sim_ros.experiments import paper

sys.path.insert(0, str(Path(__file__).parent))
from ros_env import isolated_env, pick_domain_id  # noqa: E402


@pytest.fixture(scope="module")
def exp_a(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp_a")
    return out, paper.experiment_a(out, steps=220, snapshot_steps=(0, 150, 220), progress=False)


def test_a_run_that_held_says_so(exp_a):
    assert exp_a[1].summary["run held"] == "yes"


def test_a_collapsed_run_says_so_and_fails_and_a_nonsense_dt_is_warned_about(tmp_path, capsys):
    """``experiment a --set dt=10`` exited 0 with "diverged steps: 0, energy finite: True" while its snapshots
    showed the mesh smeared from top to bottom."""
    from tissue_sim_ros.cli import main

    code = main(["experiment", "a", "--out", str(tmp_path), "--set", "dt=10", "--contact", "projection",
                 "--steps", "20", "--no-progress"])
    out, err = capsys.readouterr()
    assert code == 1
    assert "run held: no: collapsed at step" in out
    warning = [line for line in err.splitlines() if "warning" in line]
    assert len(warning) == 1 and "dt=10.0 s" in warning[0] and "0.1 s" in warning[0], err
    assert any("did not hold" in line and "collapsed" in line for line in err.splitlines()), err


def test_experiment_a_writes_figures_and_finite_energy(exp_a):
    out, res = exp_a
    for name in ("experiment_a_snapshots.png", "experiment_a_energy.png", "experiment_a_energy.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 1000
    run = res.rollouts["a"]
    assert len(run.steps) == 220
    assert np.isfinite(run.total).all() and res.summary["energy finite"]
    assert res.summary["diverged steps"] == 0
    table = np.loadtxt(out / "experiment_a_energy.csv", delimiter=",", skiprows=1)
    assert table.shape[0] == 220
    np.testing.assert_array_equal(table[:, 2], run.scene_total)  # the CSV is the run, to full precision


def test_experiment_a_contact_steps_cost_more_energy_than_free_steps(exp_a):
    _, res = exp_a
    run = res.rollouts["a"]
    lower = run.total[:, 1]
    contact = run.in_contact[:, 1]
    assert contact.any() and (~contact).any()
    first = int(np.argmax(contact))
    # the tissue has settled under gravity before the tool comes near (steps 100 .. first contact)
    free = lower[100:first]
    assert free.size > 10
    assert lower[contact].mean() > 10 * free.mean()
    assert lower[contact].max() > 100 * np.median(free)


def test_experiment_a_deforms_near_the_tool_and_not_far_from_it(exp_a):
    _, res = exp_a
    run = res.rollouts["a"]
    x0, x150, x220 = run.snapshots[0], run.snapshots[150], run.snapshots[220]
    assert set(run.snapshots) == {0, 150, 220}
    model_body = _model_bodies()
    tip = np.array(tr.A_START) + tr.A_SPEED * 220 * np.array([np.cos(np.radians(tr.A_ANGLE_DEG)),
                                                               np.sin(np.radians(tr.A_ANGLE_DEG))])
    disp = np.linalg.norm(x220 - x150, axis=1)  # what the tool did between the snapshots (gravity has settled)
    dist = np.linalg.norm(x0 - tip, axis=1)
    near = (dist < 0.15) & (model_body == 1)
    far = dist > 0.6  # the far ends of both tissues: beyond the paper's r = 0.25 with room to spare
    assert near.sum() > 5 and far.sum() > 30
    assert disp[near].max() > 0.01  # the tissue under the tool moved by more than a centimetre
    assert np.median(disp[far]) < 1e-3  # the far tissue did not (sub-millimetre)
    assert disp[near].mean() > 20 * disp[far].mean()


def _model_bodies() -> np.ndarray:
    from tissue_sim_ros.core.sim.scene import build_simulation

    return build_simulation().model.particle_body


def test_experiment_b_ranks_the_two_angles(tmp_path):
    res = paper.experiment_b(tmp_path, angles_deg=(-10.0, -30.0), distance=0.12, progress=False)
    assert (tmp_path / "experiment_b.png").is_file()
    costs = res.summary["cost (energy added, summed over steps)"]
    assert set(costs) == {"-10 deg", "-30 deg"}
    assert all(np.isfinite(v) and v > 0 for v in costs.values())
    cheaper = res.summary["cheaper angle [deg]"]
    assert costs[f"{cheaper:+.0f} deg"] == min(costs.values())
    for run in res.rollouts.values():
        assert np.isfinite(run.total).all()
        # the tip ends at the common target
        assert len(run.steps) == int(np.ceil(0.12 / tr.B_SPEED - 1e-9))


def test_experiment_cli_bad_input_exits_2(tmp_path, capsys):
    from tissue_sim_ros.cli import main

    assert main(["experiment", "a", "--out", str(tmp_path), "--steps", "0", "--no-progress"]) == 2
    assert "--steps 0" in capsys.readouterr().err
    assert main(["experiment", "a", "--out", str(tmp_path), "--set", "dt=-1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "dt=-1" in err and "Traceback" not in err
    # was a 35.9 GiB MemoryError traceback: refused from the estimate before meshing
    assert main(["experiment", "a", "--out", str(tmp_path), "--set", "spacing=0.0001", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "about 7.3e+07 particles, over the limit max_particles=300000" in err[0], err


def test_experiment_cli_bad_input_creates_nothing(tmp_path, capsys):
    from tissue_sim_ros.cli import main

    out = tmp_path / "ex1"
    for extra, message in [(["--settle", "-3"], "--settle -3: expected a number of steps >= 0"),
                           (["--set", f"mesh_file={tmp_path / 'nonexist.npz'}"], "nonexist.npz' does not exist"),
                           (["--trajectory", str(tmp_path / "nonexist.csv")], "nonexist.csv' does not exist")]:
        assert main(["experiment", "a", "--out", str(out), "--no-progress", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists(), extra  # was an empty ex1/ left behind
    assert main(["experiment", "b", "--out", str(out), "--no-progress", "--set",
                 f"mesh_file={tmp_path / 'nonexist.npz'}"]) == 2
    assert not out.exists()
    (tmp_path / "afile").write_text("")
    assert main(["experiment", "a", "--out", str(tmp_path / "afile"), "--no-progress"]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err


def test_readme_names_the_files_experiment_a_writes(tmp_path, capsys):
    """The file names README and docs/paper.md (where the experiments and trajectory files are described) give are
    what `tissue-sim experiment a` writes (the README named an experiment_a_trajectory.csv that the default run does
    not write)."""
    import re

    from tissue_sim_ros.cli import main

    assert main(["experiment", "a", "--out", str(tmp_path), "--steps", "3", "--no-progress"]) == 0
    written = {p.name for p in tmp_path.iterdir()}
    root = Path(__file__).parents[1]
    readme, paper = (root / "README.md").read_text(), (root / "docs" / "paper.md").read_text()
    for doc in (readme, paper):
        named = set(re.findall(r"experiment_a_(?:paper|projection)_\w+\.(?:csv|png)", doc))
        assert named and named <= written, named - written
    for name in sorted(n for n in written if n.endswith("_trajectory.csv")):
        assert f"`{name}`" in paper, name


def _mcap_messages(bag_dir: Path) -> dict[str, list[bytes]]:
    """Every message of the bag's MCAP file(s) by topic, read with the independent `mcap` library."""
    from mcap.reader import make_reader

    out: dict[str, list[bytes]] = {}
    files = sorted(bag_dir.glob("*.mcap"))
    assert files, f"no .mcap file in {bag_dir}"
    for f in files:
        with open(f, "rb") as fh:
            for _schema, channel, message in make_reader(fh).iter_messages():
                out.setdefault(channel.topic, []).append(message.data)
    return out


def _cdr_float64(data: bytes) -> float:
    # CDR: 4-byte encapsulation header (little endian = 0x0001), then the double aligned to 8 from the payload start
    assert data[:2] == b"\x00\x01"
    return struct.unpack_from("<d", data, 4)[0]


def _run_demo(out: Path, *args: str) -> subprocess.CompletedProcess:
    """``tissue-sim demo`` as a newcomer runs it, on a ROS domain of its own (localhost only); it ends its own
    node, recorder and driver (the demo stops every process it started, also on an error)."""
    env = isolated_env(pick_domain_id())
    proc = subprocess.run([str(Path(sys.executable).parent / "tissue-sim"), "demo", "--out", str(out),
                           "--domain-id", env["ROS_DOMAIN_ID"], "--timeout", "120", *args],
                          env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def _uint32(data: bytes) -> int:
    assert data[:2] == b"\x00\x01"
    return struct.unpack_from("<I", data, 4)[0]


def _summary_agrees_with_the_bag(out: Path, stdout: str) -> dict:
    """The demo's summary, its energy CSV (the series its plot draws) and its bag, read with the independent
    `mcap` reader, agree on the energy (peak per body, its step, the total of every term) and on contact."""
    import re

    from tissue_sim_ros.ros.messages import CONTACT_FIELDS, decode_float64_multiarray

    msgs = _mcap_messages(out / "demo_bag")
    energy = np.array([_cdr_float64(m) for m in msgs["/tissue/energy"]])
    tables = [decode_float64_multiarray(m) for m in msgs["/tissue/energy/bodies"]]
    names = tables[0][1][0].split(":", 1)[1].split(",")
    terms = tables[0][1][1].split(":", 1)[1].split(",")
    bodies = np.array([t[0] for t in tables]).reshape(len(tables), len(names), len(terms))
    total = bodies[:, :, terms.index("total")]
    np.testing.assert_allclose(total.sum(axis=1), energy, rtol=1e-12, atol=0)
    # the summary: each body's peak and its step, as the bag has them
    line = re.search(r"Peak implicit Euler energy \(every term: ([^)]*)\) (.*) at steps ([\d, ]+);", stdout)
    assert line, stdout[-2000:]
    for name, peak, step in zip(names, total.max(axis=0), total.argmax(axis=0) + 1):
        assert re.search(rf"{re.escape(name)} {peak:.4g}\b", line.group(2)), (name, peak, line.group(0))
    assert [int(s) for s in line.group(3).split(",")] == list(total.argmax(axis=0) + 1), line.group(0)
    # the CSV the plot is drawn from: the bag's total per body, and every term adding up to it
    header = (out / "demo_energy.csv").read_text().splitlines()[0].split(",")
    csv = np.loadtxt(out / "demo_energy.csv", delimiter=",", skiprows=1)
    for b, name in enumerate(names):
        cols = [i for i, h in enumerate(header) if h.startswith(f"{name}:")]
        col_total = header.index(f"{name}:total")
        np.testing.assert_allclose(csv[:, col_total], total[:, b], rtol=1e-12, atol=0)
        parts = [i for i in cols if i != col_total]
        np.testing.assert_allclose(csv[:, parts].sum(axis=1), total[:, b], rtol=1e-9, atol=1e-15 + 1e-9 * total.max())
    # contact: a step touches when any body is in contact or a grasper holds tissue
    contact = np.array([decode_float64_multiarray(m)[0][:, CONTACT_FIELDS.index("in_contact")] > 0.5
                        for m in msgs["/tissue/contact"]]).any(axis=1)
    held = np.array([_uint32(m) for m in msgs.get("/tool/grasped", [])], dtype=np.int64)
    touched_bag = contact.copy()
    touched_bag[: len(held)] |= held > 0
    touched = re.search(r"touched the tissue in (\d+) steps \(first at step (\d+|-)\)", stdout)
    assert touched and int(touched.group(1)) == int(touched_bag.sum()), (touched.group(0), int(touched_bag.sum()))
    first = int(np.argmax(touched_bag)) + 1 if touched_bag.any() else None
    assert touched.group(2) == (str(first) if first else "-")
    np.testing.assert_array_equal(csv[:, header.index("touched")], touched_bag)
    assert "Run held: yes" in stdout
    return {"energy": energy, "total": total, "touched": touched_bag, "held": held, "msgs": msgs,
            "terms": line.group(1).split(", ")}


@pytest.mark.parametrize("scene", ["liver_probe", "retract"])
def test_demo_of_a_material_scene_reports_the_energy_and_contact_its_bag_holds(tmp_path, scene):
    """``demo --scene liver_probe`` printed the inertial term as its energy (6.68e-09 at step 3 where the bag
    peaks at 3.11e-08 at step 400); ``--scene retract`` printed 0 contact steps while the grasper held the flap
    for 257, and its snapshots cut the lifted flap off without drawing the grasper."""
    out = tmp_path / "out"
    proc = _run_demo(out, "--scene", scene)
    got = _summary_agrees_with_the_bag(out, proc.stdout)
    assert "strain" in got["terms"]  # the material's term is counted
    if scene == "liver_probe":
        assert int(np.argmax(got["energy"])) + 1 > 300  # the probe presses deepest at the end
    else:
        assert "attach" in got["terms"] and (got["held"] > 0).sum() > 100
        assert f"holding it in {(got['held'] > 0).sum()} of them" in proc.stdout
    assert (out / "demo_snapshots.png").stat().st_size > 1000 and (out / "demo_energy.png").stat().st_size > 1000


def test_demo_runs_through_ros_and_its_bag_decodes_with_mcap(tmp_path):
    out = tmp_path / "out"
    proc = _run_demo(out)
    assert "real-time factor" in proc.stdout
    import re

    _summary_agrees_with_the_bag(out, proc.stdout)
    touched = re.search(r"touched the tissue in (\d+) steps \(first at step (\d+)\)", proc.stdout)
    assert touched and int(touched.group(1)) > 0 and 100 < int(touched.group(2)) < 300, proc.stdout[-2000:]
    for name in ("demo_snapshots.png", "demo_energy.png"):
        assert (out / name).stat().st_size > 1000
    msgs = _mcap_messages(out / "demo_bag")
    steps = tr.experiment_a(paper.build_simulation().tool, 0.01).n_steps(0.01)
    assert len(msgs["/tissue/energy"]) == steps
    energy = np.array([_cdr_float64(m) for m in msgs["/tissue/energy"]])
    assert np.isfinite(energy).all() and (energy >= 0).all()
    assert len(msgs["/tissue/points"]) == steps and len(msgs["/tool/wrench"]) == steps
    assert len(msgs["/tool/pose"]) >= steps
    # the recording carries the node's parameters, so the plain replay steps with the node's physics
    # (projection contact here), not the shipped defaults (paper contact): the node's energies again
    import json

    from tissue_sim_ros.cli import main as cli
    from tissue_sim_ros.ros.bags import Bag

    with Bag(out / "demo_bag") as bag:
        recorded = json.loads(bag.custom_data["tissue_sim.params"])
    assert recorded["contact_model"] == "projection" and recorded["lock_step"] is True
    for mode in ("per-message", "applied"):
        replay_out = tmp_path / f"replay_{mode}"
        assert cli(["replay", str(out / "demo_bag"), "--mode", mode, "--out", str(replay_out), "--no-progress",
                    "--frame-every", "-1", "--no-bag"]) == 0
        summary = json.loads((replay_out / "replay.json").read_text())
        assert summary["params_source"] == "bag" and summary["steps"] == steps
        replayed = np.loadtxt(replay_out / "energy.csv", delimiter=",", skiprows=1, usecols=2)  # energy_total
        if mode == "applied":  # the tool the node stepped with: the live run, bit for bit
            np.testing.assert_array_equal(replayed, energy)
            # contact counted from tissue/contact (every step), not from the markers (a display stream that
            # skips steps): the demo's count is the replay's, step for step
            assert int(touched.group(1)) == summary["steps_in_contact"], (touched.group(0), summary)
        else:  # the driver's poses and twists: the same physics (the shipped paper contact was off by ~1000x)
            np.testing.assert_allclose(replayed, energy, rtol=0, atol=1e-3 * energy.max())


def test_plan_ranks_insertions_on_two_processes(tmp_path, capsys):
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.experiments.plan import angle_grid, plan

    assert angle_grid(-10, -30, 10) == [-10, -20, -30]
    rows = plan({"tool_length": 0.3}, [-10.0, -30.0], [0.002], tr.B_TARGET, 0.06, jobs=2, progress=False)
    assert [r["cost"] for r in rows] == sorted(r["cost"] for r in rows)
    assert {r["angle_deg"] for r in rows} == {-10.0, -30.0}
    assert all(r["finite"] and r["steps"] == 30 for r in rows)
    # the worker result equals the same insertion run here (processes change nothing)
    from tissue_sim_ros.experiments.plan import evaluate

    again = evaluate({"tool_length": 0.3}, rows[0]["angle_deg"], 0.002, tr.B_TARGET, 0.06)
    assert again["cost"] == rows[0]["cost"]
    code = main(["plan", "--angles", "-10", "-30", "20", "--speeds", "0.002", "--distance", "0.04", "--jobs", "1",
                 "--out", str(tmp_path), "--no-progress"])
    assert code == 0 and (tmp_path / "plan.png").is_file() and (tmp_path / "plan.csv").is_file()
    assert "cheapest" in capsys.readouterr().out
    assert main(["plan", "--speeds", "-1", "--out", str(tmp_path), "--no-progress"]) == 2


def test_plan_refuses_a_target_outside_the_tissue(tmp_path, capsys):
    """As the node's planner service does: every insertion would cost 0 (was exit 0 with a note)."""
    from tissue_sim_ros.cli import main

    out = tmp_path / "plan"
    assert main(["plan", "--target", "5", "5", "--jobs", "1", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--target 5 5" in err and "is outside the tissue: expected a target inside it" in err
    assert not out.exists()


def test_a_trajectory_shorter_than_one_step_is_refused_everywhere(tmp_path, capsys):
    """A one-row CSV ran experiment a for 0 steps, exit 0, empty figures (replay refused it): now every command
    that runs a trajectory refuses it in one line, and writes nothing."""
    from tissue_sim_ros.cli import main

    one = tmp_path / "one.csv"
    one.write_text("time,x,y,yaw\n0,0.1,0.5,0\n")
    for argv in (["experiment", "a", "--trajectory", str(one), "--out", str(tmp_path / "a")],
                 ["experiment", "b", "--trajectory", str(one), "--out", str(tmp_path / "b")],
                 ["replay", "--trajectory", str(one), "--out", str(tmp_path / "r")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"trajectory {str(one)!r} lasts 0.0 s: shorter than one step of dt=0.01 s" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.csv"]


def test_experiment_retract_reports_the_flaps_height_and_that_it_held(tmp_path):
    """``experiment retract`` printed "surface at x [m]" for the flap's top, a height."""
    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.core.resources import scene_params_file
    from tissue_sim_ros.experiments.retract import experiment_retract

    res = experiment_retract(tmp_path, params=resolve_config(params_file=scene_params_file("retract")), progress=False)
    assert "surface at x [m]" not in res.summary
    key = next(k for k in res.summary if "height" in k)
    assert "x = 0.04 m" in key and "y [m]" in key and 0.0 < res.summary[key] < 0.03
    assert res.summary["run held"] == "yes"
