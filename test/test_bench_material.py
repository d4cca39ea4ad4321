"""The material benchmarks (tiny versions) and the exact membrane energy they measure against."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from tissue_sim_ros.bench import material_accuracy as ma
from tissue_sim_ros.bench import refinement
from tissue_sim_ros.bench.material_reference import MembraneEnergy, lame
from tissue_sim_ros.bench.reference import minimize_step
from tissue_sim_ros.cli import main
from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.sim.simulation import Simulation

pytest.importorskip("skfem")

STRIP = {"material": "neo_hookean", "young_modulus": 50e3, "poisson_ratio": 0.45, "thickness": 1e-3,
         "density": 1000.0, "dt": 0.002, "boundary_y_top": 0.04 - 1e-9, "boundary_y_bottom": math.nan,
         "contact_model": "none"}


@pytest.fixture(scope="module")
def stepped():
    sim = Simulation.from_config(resolve_config(STRIP), mesh=mesh_rectangle(0.1, 0.04, 0.01))
    for _ in range(4):
        report = sim.step()
    return sim, report


def test_lame_and_shift():
    # plane stress lambda = E nu / (1 - nu^2), mu = E / (2 (1 + nu)); the form's lambda' = lambda + mu
    lam, mu, shifted = lame(1000.0, 0.25)
    assert (lam, mu, shifted) == pytest.approx((266.6666666666667, 400.0, 666.6666666666667), rel=1e-14)


def test_membrane_energy_is_the_simulators(stepped):
    # two codes, one energy: the simulator's published potential and total equal this module's
    sim, report = stepped
    e = MembraneEnergy(sim.model, report.x_pred, sim.params.dt)
    x = sim.state.particle_q
    assert e.strain_energy(x) == pytest.approx(report.energy.scene_potential, rel=1e-10)
    assert e.value(x) == pytest.approx(report.energy.scene_total, rel=1e-10)


def test_membrane_energy_vanishes_at_rest_and_under_rotation(stepped):
    sim, _ = stepped
    q0 = sim.model.particle_q0
    e = MembraneEnergy(sim.model, q0, 0.002)
    c, s = math.cos(0.7), math.sin(0.7)
    rotated = q0 @ np.array([[c, s], [-s, c]]) + np.array([0.3, -0.1])
    # round-off scale: mu V (1e-16)^2 per element for F = I + O(1e-16)
    scale = 50e3 * e.volume.sum()
    assert e.strain_energy(q0) <= 1e-24 * scale
    assert e.strain_energy(rotated) <= 1e-24 * scale
    stretched = q0 * np.array([1.01, 1.0])  # and not under a stretch
    assert e.strain_energy(stretched) > 1e-6 * scale


def test_gradient_and_hessian_match_finite_differences(stepped):
    # central differences, step 1e-7 m on a 1e-3 m perturbation: truncation O(eps^2), round-off O(1e-16/eps)
    sim, report = stepped
    e = MembraneEnergy(sim.model, report.x_pred, 0.002)
    rng = np.random.default_rng(3)
    y = sim.state.particle_q + rng.normal(0, 1e-3, sim.state.particle_q.shape)
    d = rng.normal(size=y.shape)
    eps = 1e-7
    fd = (e.value(y + eps * d) - e.value(y - eps * d)) / (2 * eps)
    assert float(e.gradient(y).ravel() @ d.ravel()) == pytest.approx(fd, rel=1e-6)
    hd = e.hessian(y) @ d.ravel()
    fd2 = (e.gradient(y + eps * d) - e.gradient(y - eps * d)).ravel() / (2 * eps)
    assert np.abs(hd - fd2).max() <= 1e-6 * np.abs(hd).max()
    # projection only removes negative curvature
    hp = e.hessian(y, project=True)
    assert float(d.ravel() @ (hp @ d.ravel())) > 0


def test_more_iterations_approach_the_exact_step(stepped):
    # the exact minimiser is what the solve approaches: 10 x 10 closer to it than 1 x 5
    cfg = resolve_config(STRIP)
    mesh = mesh_rectangle(0.1, 0.04, 0.01)
    coarse = ma.measure(cfg, mesh, "gauss_seidel", 1, 5, 2)
    fine = ma.measure(cfg, mesh, "gauss_seidel", 10, 10, 2)
    assert fine["err_response_max"] < 0.1 * coarse["err_response_max"]
    assert coarse["err_response_median"] <= coarse["err_response_max"]
    assert fine["reference_rel_grad_max"] < 1e-5


def test_exact_step_is_a_fixed_point_at_equilibrium():
    # a state at rest that is the static equilibrium stays there: Newton from x* = x + h^2 g returns x
    sim = Simulation.from_config(resolve_config({**STRIP, "damping": 50.0}), mesh=mesh_rectangle(0.1, 0.04, 0.02))
    refinement.run_to_rest(sim, None, 1e-9, 5000)
    start = sim.state.copy()
    x = ma.exact_step(sim, start)
    fixed = sim.model.particle_inv_mass == 0
    e = MembraneEnergy(sim.model, start.particle_q, sim.params.dt)
    assert np.abs(x - start.particle_q).max() < 1e-3 * np.abs(start.particle_q - sim.model.particle_q0).max()
    assert minimize_step(e, fixed)[1]["converged"]


def test_pareto_front():
    rows = [{"solve_ms_median": 1.0, "err_response_max": 0.5}, {"solve_ms_median": 2.0, "err_response_max": 0.1},
            {"solve_ms_median": 3.0, "err_response_max": 0.2}, {"solve_ms_median": 0.5, "err_response_max": 0.9}]
    assert ma.pareto(rows) == [3, 0, 1]


def test_bench_material_quick(tmp_path, capsys):
    assert main(["bench", "material", "--quick", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "material_accuracy.csv")))
    assert len(rows) == len(ma.QUICK_SETTINGS)
    assert (tmp_path / "material_accuracy.png").stat().st_size > 0
    assert "Pareto front" in capsys.readouterr().out


def test_bench_refinement_quick(tmp_path, capsys):
    # 20 mm and 10 mm only: the errors against the FEM fall with refinement (strip sag, punch force)
    assert main(["bench", "refinement", "--quick", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "refinement.csv")))
    spacing = [r for r in rows if r["study"] == "spacing"]
    strip = [abs(float(r["err_mean_sag"])) for r in spacing if r["problem"] == "hanging_strip"]
    punch = [abs(float(r["err_force"])) for r in spacing if r["problem"] == "flat_punch"]
    assert strip[1] < strip[0] and punch[1] < punch[0]
    assert all(r["at_rest"] == "True" for r in spacing)
    dyn = [float(r["err_dynamic"]) for r in rows if r["study"] == "dt_dynamic"]
    assert dyn[1] < dyn[0]  # the dynamics converge in dt
    assert (tmp_path / "refinement.png").stat().st_size > 0
    assert "flat punch" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["bench", "refinement", "--spacings", "a,b"], ["bench", "refinement", "--dts", "-1"],
                                  ["bench", "material", "--steps", "0"], ["bench", "material", "--scenes", "moon"]])
def test_bench_bad_input_exits_2(argv, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path)]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_bench_peers_fem_quick(tmp_path, capsys):
    # ours always; MuJoCo's flex membrane when installed (the peers extra): both converge to the FEM
    from tissue_sim_ros.bench.peers import available

    assert main(["bench", "peers", "--fem", "--quick", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "peers_fem.csv")))
    ours = [abs(float(r["err_mean_sag"])) for r in rows if r["peer"] == "ours"]
    assert ours[1] < ours[0] < 0.1
    if available("mujoco"):
        mj = [r for r in rows if r["peer"] == "mujoco"]
        assert all(r["at_rest"] == "True" for r in mj)
        assert abs(float(mj[1]["err_mean_sag"])) < 0.05  # the membrane has stiffness (elastic2d is not none)
    assert "run to rest" in capsys.readouterr().out
    # the contact scenes: the default (ipc) leaves nothing inside the capsule or the other body, its tool presses
    # (the reaction of a third deep into 50 kPa is Newtons), the dropped block rests on its contact force =
    # its weight; the former default lets the block through the strip (bodies never touched)
    contact = {(r["scene"], r["peer"]): r for r in csv.DictReader(open(tmp_path / "peers_contact.csv"))}
    press, drop = contact[("press", "ours_ipc")], contact[("drop", "ours_ipc")]
    assert int(press["inside"]) == 0 and float(press["depth_m"]) == 0.0 and float(press["force_N"]) > 1.0
    assert int(drop["inside_max"]) == 0 and float(drop["gap_m"]) > 0.0
    assert float(drop["force_over_weight"]) == pytest.approx(1.0, abs=0.01)
    assert int(contact[("drop", "ours_former")]["inside_max"]) > 0
    if available("mujoco"):
        assert ("press", "mujoco") in contact and ("drop", "mujoco") in contact
    assert (tmp_path / "peers_contact.png").stat().st_size > 0


def test_bench_stability_material_quick(tmp_path, capsys):
    # a gentle press and a drag of each scheme, and the hardest press of the box: a 1 m/s tool at dt 20 ms jumps
    # 2 cm per step (4x its own width) into a sliver mesh of a 1 MPa tissue. The default (ipc) holds in every run
    # (its tool stops short where it must; in the hardest it stiffens its barrier, and its reaction stays the
    # load's, 24 N: with a fixed stiffness the held steps stopped short and it read up to 1e8 N); the former
    # default (quasi_newton + projection) ends inside the tissue
    from tissue_sim_ros.bench import material_stability as ms

    assert main(["bench", "stability", "--material", "--quick", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "material_stability.csv")))
    assert len(rows) == len(ms.sweep(True)) == 6
    assert {r["motion"] for r in rows} == {"press", "drag"}
    ipc = [r for r in rows if r["scheme"] == "ipc"]
    assert all(r["outcome"] == "stable" for r in ipc), [(r["motion"], r["outcome"], r["detail"]) for r in ipc]
    assert all(int(r["unconverged_steps"]) == 0 for r in ipc)
    assert all(0 < float(r["max_reaction_n"]) < 100 for r in ipc)
    assert all(float(r["max_penetration_m"]) == 0.0 and int(r["max_inverted"]) == 0 for r in ipc)
    # the lag is a distance the tool stopped short: finite, >= 0, and far below the travel here
    assert all(0.0 <= float(r["lag_end_m"]) <= float(r["lag_max_m"]) < 1e-3 for r in ipc)
    former = {(r["motion"], r["young_modulus"]): r for r in rows if r["scheme"] == "quasi_newton"}
    assert former[("press", "1000.0")]["outcome"] == "stable"
    assert former[("press", "1000000.0")]["outcome"] in ("buried", "tunnelling", "penetrating")
    assert all(float(r["lag_end_m"]) == 0.0 for r in former.values())  # projection: the tool goes where it is sent
    assert all(int(r["steps_run"]) >= 1 and float(r["iterations_median"]) >= 1 for r in rows)
    assert (tmp_path / "material_stability.png").stat().st_size > 0
    printed = capsys.readouterr()
    assert "[6/6]" in printed.out + printed.err  # a progress line per run


def test_material_stability_poses_press_a_third_deep_and_drag():
    from tissue_sim_ros.bench import material_stability as ms

    below = 0.5 * ms.TOOL.length + ms.TOOL.radius  # the capsule's lowest point below its pose
    ps = ms.poses(0.01, 0.1)
    tip = [p.y - below for p in ps]
    assert tip[0] == pytest.approx(ms.HEIGHT + 0.002)
    assert tip[-1] == pytest.approx(ms.HEIGHT - ms.HEIGHT / 3)
    assert ps[-1] == ps[-ms.HOLD_STEPS]  # held at the end
    # each move at the tool speed: 1 mm per step at 0.1 m/s and dt 10 ms
    assert max(abs(a.y - b.y) for a, b in zip(ps, ps[1:])) == pytest.approx(0.001, rel=0.05)
    drag = ms.poses(0.01, 0.1, "drag")
    assert drag[0].y - below == pytest.approx(ms.HEIGHT + 0.002)
    assert drag[-1].y - below == pytest.approx(ms.HEIGHT - ms.DRAG_DEPTH)
    assert drag[-1].x - drag[0].x == pytest.approx(ms.DRAG_DISTANCE)
    assert len(drag) == 1 + 5 + 20 + ms.HOLD_STEPS
    # the slowest run is capped at MAX_STEPS steps of motion
    assert len(ms.poses(0.001, 0.01, "drag")) <= 1 + ms.MAX_STEPS + ms.HOLD_STEPS


def test_tune_material_quick_writes_a_file_that_reproduces_its_setting(tmp_path, capsys):
    # the real-size scene through the same path as the full run, on a tiny candidate set: a uniform and a
    # graded 6 mm mesh against a 3 mm reference graded to 1.5 mm at the instrument
    from tissue_sim_ros.core.resources import scene_params_file
    from tissue_sim_ros.tune import material as tm

    scene = scene_params_file("liver_probe")
    out = tmp_path / "tuned.yaml"
    csv_path = tmp_path / "tune.csv"
    code = main(["tune", "--params", str(scene), "--tolerance", "0.7", "--budget-ms", "1e6", "--quick",
                 "--out", str(out), "--csv", str(csv_path), "--png", str(tmp_path / "tune.png")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "chosen:" in printed and "verified" in printed
    assert (tmp_path / "tune.png").stat().st_size > 0
    rows = list(csv.DictReader(open(csv_path)))
    uniform = [r for r in rows if float(r["grade_spacing"]) == 0]
    graded = [r for r in rows if float(r["grade_spacing"]) > 0]
    assert uniform and graded
    # the graded mesh's mesh error is below the uniform one's in every quantity (the contact resolved)
    for q in tm.QUANTITIES:
        assert float(graded[0][f"mesh_{q}"]) < float(uniform[0][f"mesh_{q}"])
    # the error is the worst quantity's mesh + solver sum
    for r in rows:
        sums = [float(r[f"mesh_{q}"]) + float(r[f"solver_{q}"]) for q in tm.QUANTITIES]
        assert float(r["error"]) == pytest.approx(max(sums), rel=1e-12)
    # the written file resolves through the front door and reproduces the chosen setting and mesh
    cfg = resolve_config(params_file=out)
    chosen = [r for r in rows if float(r["spacing"]) == cfg.scene.spacing
              and float(r["grade_spacing"]) == cfg.scene.grade_spacing and int(r["substeps"]) == cfg.sim.substeps
              and int(r["iterations"]) == cfg.sim.iterations
              and float(r["solve_tolerance"]) == cfg.sim.solve_tolerance]
    assert len(chosen) == 1 and float(chosen[0]["error"]) <= 0.7
    assert cfg.scene.grade_spacing > 0 and cfg.scene.grade_radius == pytest.approx(2 * cfg.tool.radius)
    assert len(cfg.scene.build_mesh().vertices) == int(chosen[0]["particles"])
    assert cfg.sim.material == "neo_hookean" and cfg.sim.young_modulus == 4000.0
    assert cfg.sim.method == "ipc" and cfg.sim.substeps == 1  # the scene's own method: its tolerance tuned
    # run as written, against the same reference directly: within the mesh + solver bound, per quantity
    ref = tm.build_reference(resolve_config(params_file=scene), *tm.reference_meshes([0.006], [0.003]), 0.003,
                             tm.solver_settings(cfg, quick=True)[1], progress=lambda _: None)
    assert (ref["press"].x, ref["press"].top) == \
        pytest.approx((cfg.scene.grade_x, cfg.scene.grade_y))
    direct = tm.verify(cfg, ref)
    for q in tm.QUANTITIES:
        assert direct[f"err_{q}"] <= float(chosen[0][f"err_{q}"]) + 1e-9
    assert main(["tune", "--params", str(out), "--verify", "--quick", "--tolerance", "0.7", "--budget-ms", "1"]) == 0


def test_graded_scene_parameters_are_checked():
    base = {"spacing": 0.005}
    with pytest.raises(InputError, match="grade_spacing=0.01: expected 0 .uniform. or a spacing in"):
        resolve_config({**base, "grade_spacing": 0.01})
    with pytest.raises(InputError, match="grade_radius=-0.001: expected a radius >= 0"):
        resolve_config({**base, "grade_spacing": 0.001, "grade_radius": -0.001})
    assert resolve_config(base).scene.grading is None
    assert resolve_config({**base, "grade_spacing": 0.001, "grade_x": 0.1, "grade_y": 0.2,
                           "grade_radius": 0.01}).scene.grading == (0.1, 0.2, 0.01, 0.001)

def test_bench_material_speed_quick(tmp_path, capsys):
    """The command runs end to end; on its two coarse meshes the default solve is converged (within 1% of the FEM
    sag, the punch within 2%) where xpbd 10 x 10 at dt 10 ms is not, and each contact step is within 1% of the
    exact step. Its times are printed, never asserted."""
    assert main(["bench", "material-speed", "--quick", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "material_speed.csv")))
    qn = [r for r in rows if r["variant"] == "quasi_newton"]
    assert len(qn) == 2 and all(abs(float(r["err_sag"])) < 0.01 for r in qn)
    assert all(float(r["solve_residual_max"]) <= 1e-3 for r in qn)
    xpbd = [r for r in rows if r["variant"] == "xpbd 10x10"]
    assert float(xpbd[-1]["solve_residual_max"]) > 1e-3  # the former default says it stopped short
    punch = [r for r in csv.DictReader(open(tmp_path / "material_accuracy_punch.csv")) if r["variant"] == "quasi_newton"]
    assert all(abs(float(r["err_force"])) < 0.02 and int(r["penetrating"]) == 0 for r in punch)
    dyn = list(csv.DictReader(open(tmp_path / "material_dynamics.csv")))
    assert all(float(r["err_step_max"]) < 0.01 for r in dyn)
    assert (tmp_path / "material_speed.png").stat().st_size > 0
    assert "wrote" in capsys.readouterr().out
