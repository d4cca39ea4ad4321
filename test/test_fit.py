"""tissue-sim fit: tracked points bound to the mesh, rollouts at observation stamps, the fit, bad input.

The references: barycentric coordinates reproduce the points they were made
from; a free-falling tissue's points follow the discrete implicit-Euler fall
y_k = y_0 - g dt^2 k (k + 1) / 2 between steps linearly; and recordings made by
the simulator with known parameters on a finer mesh than the fit's, with
0.5 mm noise, give those parameters back within the issue's tolerances with
95% intervals that hold them. Recordings are tiny (a 1.5 s press, 20 points,
8 mm fit mesh) so that each fit runs in a few seconds.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tissue_sim_ros.cli import fit as fitcli
from tissue_sim_ros.cli import main as cli
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.fit.fitting import autocorrelation_time, fit, make_parameter
from tissue_sim_ros.core.fit.tracking import (
    PoolTrackSimulator,
    Recording,
    SceneFactory,
    Schedule,
    SerialTrackSimulator,
    bind_points,
    binding_from_correspondence,
    rollout_tracks,
)
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.sim.scene import build_simulation, load_params_file
from tissue_sim_ros.experiments import fit_scene as fs
from tissue_sim_ros.ros import messages as m
from tissue_sim_ros.ros.bags import BagWriter
from tissue_sim_ros.ros.recording import POINT_CLOUD_TYPE, TRACKED_DTYPE, read_recording, write_recording

REC_SPACING = 0.006
FIT_SPACING = 0.008
DURATION = 1.5


@pytest.fixture(scope="module")
def scene_image(tmp_path_factory):
    return fs.write_scene_image(tmp_path_factory.mktemp("scene") / "scene.png")


@pytest.fixture(scope="module")
def truth_recording(scene_image):
    """The simulator's recording of the press at a finer spacing than the fits use, 0.5 mm noise."""
    return fs.synthesize(fs.scene_params(scene_image, spacing=REC_SPACING, **fs.TRUTH), n_points=20, noise=5e-4,
                         seed=1, duration=DURATION)


def _recording(syn) -> Recording:
    return Recording(syn.t_ns, syn.points, syn.tool_t_ns, syn.tool_pose, source="test")


def _write_scene(path, image, **overrides):
    import yaml

    path.write_text(yaml.safe_dump({"tissue_sim_node": {"ros__parameters": fs.scene_params(
        image, spacing=FIT_SPACING, **overrides)}}, sort_keys=False))
    return path


# --------------------------------------------------------------------------- binding and interpolation


def test_barycentric_binding_reproduces_the_points():
    mesh = mesh_rectangle(0.1, 0.04, 0.01)
    rng = np.random.default_rng(3)
    pts = rng.random((25, 2)) * [0.1, 0.04]
    b = bind_points(mesh.vertices, mesh.triangles, pts)
    np.testing.assert_allclose(b.positions(mesh.vertices), pts, atol=1e-15)
    assert (b.weights >= -1e-12).all() and np.allclose(b.weights.sum(axis=1), 1.0)
    # the triangle found holds the point: a naive point-in-triangle test by signed areas
    for p, tri in zip(pts, mesh.triangles[b.tri]):
        a, bb, c = mesh.vertices[tri]
        def cross(u, v):
            return u[0] * v[1] - u[1] * v[0]
        areas = [cross(bb - a, p - a), cross(c - bb, p - bb), cross(a - c, p - c)]
        assert min(areas) >= -1e-15


def test_binding_outside_the_tissue():
    mesh = mesh_rectangle(0.1, 0.04, 0.01)
    with pytest.raises(InputError, match=r"tracked point 1 at \(0.1030, 0.0200\) m is outside the tissue"):
        bind_points(mesh.vertices, mesh.triangles, np.array([[0.05, 0.02], [0.103, 0.02]]), tolerance=0.002)
    b = bind_points(mesh.vertices, mesh.triangles, np.array([[0.05, 0.02], [0.101, 0.02]]), tolerance=0.002)
    assert b.outside[1] == pytest.approx(0.001)
    # extrapolated weights still reproduce the point (barycentric coordinates are affine)
    np.testing.assert_allclose(b.positions(mesh.vertices)[1], [0.101, 0.02], atol=1e-15)


def test_correspondence_binding():
    mesh = mesh_rectangle(0.1, 0.04, 0.01)
    b = binding_from_correspondence(np.array([[3.0], [17.0]]), mesh.triangles, mesh.vertices.shape[0])
    np.testing.assert_allclose(b.positions(mesh.vertices), mesh.vertices[[3, 17]])
    with pytest.raises(InputError, match="sum to 1"):
        binding_from_correspondence(np.array([[0, 0.5, 0.5, 0.5]]), mesh.triangles, mesh.vertices.shape[0])
    with pytest.raises(InputError, match="vertex indices"):
        binding_from_correspondence(np.array([[1e6]]), mesh.triangles, mesh.vertices.shape[0])


def test_free_fall_points_at_observation_stamps():
    # reference: XPBD without contact on an unpinned mesh falls rigidly; implicit Euler positions are
    # y_k = y_0 + g dt^2 k (k + 1) / 2 at the steps, and the tracked points between steps are linear in time
    mesh = mesh_rectangle(0.1, 0.04, 0.02)
    values = {"method": "xpbd", "contact_model": "none", "boundary_y_top": 1.0, "boundary_y_bottom": -1.0,
              "dt": 0.01, "tool_shape": "sphere", "tool_radius": 0.005}
    sim = build_simulation(values, mesh=mesh)
    pts = np.array([[0.031, 0.017], [0.07, 0.03]])
    b = bind_points(mesh.vertices, mesh.triangles, pts)
    t_obs = np.array([0, 13_000_000, 26_500_000, 50_000_000, 91_000_000], dtype=np.int64)
    rec = Recording(t_obs, np.repeat(pts[None], 5, axis=0), np.array([0, 10**9]), np.array([[1.0, 1.0, 0], [1.0, 1.0, 0]]))
    sched = Schedule.from_recording(rec, 0.01)
    assert sched.n_steps == 10  # 91 ms needs the 10th step
    out = rollout_tracks(sim, b, sched, 5)
    dt, g = 0.01, -9.8
    k = (t_obs * 1e-9) / dt
    k0 = np.floor(k + 1e-9)
    y = lambda n: g * dt * dt * n * (n + 1) / 2  # noqa: E731
    expect = y(k0) + (k - k0) * (y(k0 + 1) - y(k0))
    np.testing.assert_allclose(out.points[:, :, 1] - pts[None, :, 1], np.repeat(expect[:, None], 2, axis=1), atol=1e-12)
    np.testing.assert_allclose(out.points[:, :, 0], np.repeat(pts[None, :, 0], 5, axis=0), atol=1e-12)


def test_autocorrelation_time():
    rng = np.random.default_rng(0)
    white = rng.normal(size=(400, 30))
    assert autocorrelation_time(white) == pytest.approx(1.0, abs=0.15)
    # an AR(1) series with phi = 0.8: tau = (1 + phi) / (1 - phi) = 9
    x = np.zeros((4000, 30))
    for t in range(1, 4000):
        x[t] = 0.8 * x[t - 1] + rng.normal(size=30)
    assert autocorrelation_time(x) == pytest.approx(9.0, rel=0.2)


def test_pool_equals_serial(scene_image, truth_recording):
    rec = _recording(truth_recording)
    values = fs.scene_params(scene_image, spacing=FIT_SPACING)
    sim = build_simulation(values)
    factory = SceneFactory(values, sim.model.mesh)
    b = bind_points(sim.model.particle_q0, sim.model.tri_indices, rec.points[0], tolerance=FIT_SPACING / 2)
    sched = Schedule.from_recording(rec, 0.01)
    cands = [{"young_modulus": 4e3}, {"young_modulus": 6e3, "poisson_ratio": 0.2}, {"damping": 0.5}]
    serial = SerialTrackSimulator(factory, b, sched).simulate(cands, 20)
    with PoolTrackSimulator(factory, b, sched, 2) as pool:
        pooled = pool.simulate(cands, 20)
    for a, c in zip(serial, pooled):
        assert np.array_equal(a.points, c.points)
        assert a.contact_steps == c.contact_steps
    assert not np.array_equal(serial[0].points, serial[1].points)


# --------------------------------------------------------------------------- fits


def test_fit_recovers_the_material_on_another_mesh(scene_image, truth_recording):
    rec = _recording(truth_recording)
    setup = fitcli.prepare(rec, fs.scene_params(scene_image, spacing=FIT_SPACING), ["young_modulus", "poisson_ratio"],
                           holdout=0.2)
    assert setup.mesh.vertices.shape[0] != build_simulation(truth_recording.values).model.n_particles
    res = fitcli.run_fit(setup, jobs=1, slices=3)
    e, nu = res.estimate("young_modulus"), res.estimate("poisson_ratio")
    assert e.identifiable and nu.identifiable
    assert abs(e.value / fs.TRUTH["young_modulus"] - 1) < 0.05
    assert abs(nu.value - fs.TRUTH["poisson_ratio"]) < 0.05
    assert e.low95 <= fs.TRUTH["young_modulus"] <= e.high95
    assert nu.low95 <= fs.TRUTH["poisson_ratio"] <= nu.high95
    # noise alone is sqrt(2) 0.5 mm per point; the fit is close to it, on the held-out part too
    assert 0.65 < res.rms_fit_mm < 0.85 and 0.6 < res.rms_holdout_mm < 0.9
    assert res.contact_steps > 0
    # the slices have their minimum at the optimum
    for s in res.slices:
        assert np.argmin(s.cost) == len(s.cost) // 2


def test_cma_es_finds_the_same_modulus(scene_image, truth_recording):
    # the optional optimiser for a rough cost: the same problem, the same answer within the error bar
    setup = fitcli.prepare(_recording(truth_recording), fs.scene_params(scene_image, spacing=FIT_SPACING),
                           ["young_modulus"], holdout=0.2)
    ls = fitcli.run_fit(setup, jobs=1, slices=0, mesh_check=False).estimate("young_modulus")
    es = fitcli.run_fit(setup, jobs=1, slices=0, mesh_check=False, optimizer="cma", max_evals=40,
                        seed=1).estimate("young_modulus")
    assert es.identifiable and abs(es.value - ls.value) < 2 * ls.sigma
    assert abs(es.value / fs.TRUTH["young_modulus"] - 1) < 0.05


def test_start_values_far_off_fit_worse(scene_image, truth_recording):
    # the same recording simulated with the start values misses by far more than the noise: the fit did work
    rec = _recording(truth_recording)
    setup = fitcli.prepare(rec, fs.scene_params(scene_image, spacing=FIT_SPACING), ["young_modulus"], holdout=0.0)
    start = SerialTrackSimulator(setup.factory, setup.binding, setup.schedule).simulate([{}], rec.n_frames)[0]
    from tissue_sim_ros.core.fit.tracking import rms_mm

    assert rms_mm(start.points[1:], rec.points[1:]) > 2 * math.sqrt(2) * 0.5  # twice the noise's RMS


def test_not_identifiable_without_gravity(scene_image):
    # without gravity the tool prescribes the displacement: E changes forces, not positions (no effect);
    # Poisson's ratio still shapes the displacement field and is identified
    syn = fs.synthesize(fs.scene_params(scene_image, spacing=REC_SPACING, gravity=0.0, **fs.TRUTH), n_points=20,
                        noise=5e-4, seed=2, duration=DURATION)
    setup = fitcli.prepare(_recording(syn), fs.scene_params(scene_image, spacing=FIT_SPACING, gravity=0.0),
                           ["young_modulus", "poisson_ratio"], holdout=0.2)
    res = fitcli.run_fit(setup, jobs=1, slices=0)
    e, nu = res.estimate("young_modulus"), res.estimate("poisson_ratio")
    assert not e.identifiable and e.value is None and "no effect on the observed points" in e.reason
    assert nu.identifiable and abs(nu.value - fs.TRUTH["poisson_ratio"]) < 0.05


def test_not_identifiable_when_the_tool_never_touches(scene_image):
    far = {"gravity": 0.0}
    syn = fs.synthesize(fs.scene_params(scene_image, spacing=REC_SPACING, **far, **fs.TRUTH), n_points=10,
                        noise=5e-4, seed=3, duration=0.6)
    # the tool 10 cm above the tissue all along
    syn.tool_pose[:, 1] += 0.1
    setup = fitcli.prepare(_recording(syn), fs.scene_params(scene_image, spacing=FIT_SPACING, **far),
                           ["young_modulus", "poisson_ratio"], holdout=0.0)
    res = fitcli.run_fit(setup, jobs=1, slices=0)
    for e in res.estimates:
        assert not e.identifiable and "the tool never touches the tissue" in e.reason, e


def test_only_a_combination(scene_image, truth_recording):
    # E and density enter the motion only as E / rho (the weight and the inertia both scale with rho)
    setup = fitcli.prepare(_recording(truth_recording), fs.scene_params(scene_image, spacing=FIT_SPACING),
                           ["young_modulus", "density"], holdout=0.0)
    p = [make_parameter("young_modulus", 5e3), make_parameter("density", 1000.0)]
    res = fit(SerialTrackSimulator(setup.factory, setup.binding, setup.schedule), setup.recording.points, p,
              n_fit_frames=setup.n_fit_frames, slices=0, max_nfev=4)
    reasons = {e.name: e.reason for e in res.estimates}
    assert "only a combination with density" in reasons["young_modulus"], reasons
    assert "only a combination with young_modulus" in reasons["density"], reasons


def _two_blocks(spacing: float):
    """Two 45 mm x 40 mm blocks side by side with a 10 mm gap: two bodies."""
    from tissue_sim_ros.core.mesh import mesh_from_arrays

    a = mesh_rectangle(0.045, 0.04, spacing, origin=(-0.05, 0.0))
    b = mesh_rectangle(0.045, 0.04, spacing, origin=(0.005, 0.0))
    v = np.concatenate([a.vertices, b.vertices])
    t = np.concatenate([a.triangles, b.triangles + a.vertices.shape[0]])
    return mesh_from_arrays(v, t)


def test_body_values_build_what_the_scene_builds(scene_image):
    from tissue_sim_ros.core.fit.tracking import with_body_values

    mesh = _two_blocks(0.01)
    base = fs.scene_params(scene_image, spacing=0.01)
    sim = build_simulation(base, mesh=mesh)
    assert sim.model.n_bodies == 2
    same = with_body_values(sim.model, {0: {"young_modulus": sim.params.young_modulus}, 1: {}})
    assert np.array_equal(same.tri_elastic, sim.model.tri_elastic)
    assert np.array_equal(same.particle_inv_mass, sim.model.particle_inv_mass)
    # every body at E = 7 kPa and density 800 is the scene built with those values
    ref = build_simulation({**base, "young_modulus": 7e3, "density": 800.0}, mesh=mesh).model
    both = with_body_values(sim.model, {b: {"young_modulus": 7e3, "density": 800.0} for b in (0, 1)})
    np.testing.assert_allclose(both.tri_elastic, ref.tri_elastic, rtol=1e-15)
    np.testing.assert_allclose(both.particle_mass, ref.particle_mass, rtol=1e-15)
    with pytest.raises(InputError, match="bodies 0..1"):
        with_body_values(sim.model, {2: {"young_modulus": 1e3}})


def test_per_body_fit(scene_image):
    # two tissues of different stiffness, one recording: each body's modulus comes back
    truth = {"young_modulus@0": 4e3, "young_modulus@1": 8e3}
    base = fs.scene_params(scene_image, spacing=0.006)
    fine = _two_blocks(0.006)
    syn = fs.synthesize(base, n_points=4, noise=0.0, duration=DURATION)  # its stamps and tool track
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform([-0.045, 0.01], [-0.01, 0.036], (10, 2)),
                          rng.uniform([0.01, 0.01], [0.045, 0.036], (10, 2))])
    rec0 = Recording(syn.t_ns, np.repeat(pts[None], syn.t_ns.size, axis=0), syn.tool_t_ns, syn.tool_pose)
    sched = Schedule.from_recording(rec0, 0.01)
    b = bind_points(fine.vertices, fine.triangles, pts)
    run = rollout_tracks(SceneFactory(base, fine)(truth), b, sched, syn.t_ns.size)
    obs = run.points + np.concatenate([np.zeros((1, 20, 2)), rng.normal(0, 5e-4, (syn.t_ns.size - 1, 20, 2))])
    rec = Recording(syn.t_ns, obs, syn.tool_t_ns, syn.tool_pose, source="two blocks")
    coarse = _two_blocks(FIT_SPACING)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        mesh_file = Path(tmp) / "blocks.npz"
        coarse.save(mesh_file)
        setup = fitcli.prepare(rec, {**fs.scene_params(scene_image, spacing=FIT_SPACING), "mesh_file": str(mesh_file)},
                               ["young_modulus@0", "young_modulus@1"], holdout=0.2)
        res = fitcli.run_fit(setup, jobs=1, slices=0)
        with pytest.raises(InputError, match="the scene has bodies 0..1"):
            fitcli.prepare(rec, setup.values, ["young_modulus@3"])
        with pytest.raises(InputError, match="not both"):
            fitcli.prepare(rec, setup.values, ["young_modulus", "young_modulus@1"])
    for name, value in truth.items():
        e = res.estimate(name)
        assert e.identifiable and abs(e.value / value - 1) < 0.05, e
        assert e.low95 <= value <= e.high95, e


# --------------------------------------------------------------------------- bags and the command


def test_recording_bag_round_trip(tmp_path, truth_recording):
    syn = truth_recording
    pts = syn.points.copy()
    pts[5, 3] = np.nan  # a point the tracker lost in one frame
    write_recording(tmp_path / "bag", syn.t_ns, pts, syn.tool_t_ns, syn.tool_pose)
    rec = read_recording(tmp_path / "bag", "/tracker/points", "/tool/pose")
    np.testing.assert_array_equal(rec.t_ns, syn.t_ns)
    np.testing.assert_array_equal(rec.tool_t_ns, syn.tool_t_ns)
    np.testing.assert_allclose(rec.points, pts.astype(np.float32), rtol=0, atol=0)  # float32 on the wire
    assert np.isnan(rec.points[5, 3]).all()
    np.testing.assert_allclose(rec.tool_pose, syn.tool_pose, atol=1e-12)


def test_cli_fit_writes_a_parameter_file_every_command_loads(tmp_path, scene_image, truth_recording, capsys):
    syn = truth_recording
    pts = syn.points.copy()
    pts[10:20, 4] = np.nan  # point 4 lost for ten frames: those coordinates are left out of the fit
    bag = write_recording(tmp_path / "bag", syn.t_ns, pts, syn.tool_t_ns, syn.tool_pose)
    scene = _write_scene(tmp_path / "scene.yaml", scene_image)
    out = tmp_path / "out"
    assert cli(["fit", str(bag), "--points-topic", "/tracker/points", "--tool-topic", "/tool/pose", "--params",
                str(scene), "--fit", "young_modulus,poisson_ratio", "--holdout", "0.25", "--out", str(out),
                "--no-progress", "--jobs", "1"]) == 0
    text = capsys.readouterr().out
    assert "RMS tracking error: fitted" in text and "held out" in text
    for name in ("fitted.yaml", "fit.json", "tracks.csv", "tracks.png", "errors.png", "cost.png", "summary.txt"):
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "fit.json").read_text())
    est = {p["name"]: p for p in data["parameters"]}
    assert abs(est["young_modulus"]["value"] / fs.TRUTH["young_modulus"] - 1) < 0.05
    assert data["fitted_frames"] == syn.t_ns.size - math.floor(0.25 * syn.t_ns.size)
    assert data["residuals"] == 2 * (20 * (data["fitted_frames"] - 1) - 10)
    # the parameter file: the node's format, loaded by every command and by the node's checks
    values = load_params_file(out / "fitted.yaml")
    assert values["young_modulus"] == pytest.approx(est["young_modulus"]["value"])
    from tissue_sim_ros.core.config import resolve_config

    cfg = resolve_config(params_file=out / "fitted.yaml")  # the node's and every command's front door
    assert cfg.sim.young_modulus == pytest.approx(est["young_modulus"]["value"])
    sim = build_simulation(values)
    assert sim.params.young_modulus == pytest.approx(est["young_modulus"]["value"])
    assert sim.params.material == "neo_hookean"
    rows = np.loadtxt(out / "tracks.csv", delimiter=",", skiprows=1)
    assert rows.shape == (syn.t_ns.size * syn.points.shape[1], 8)
    assert not list(tmp_path.glob(".out.*")), "the staging directory is gone"


def _cloud_bag(path, t_ns, widths, tool=True, tool_t=None):
    with BagWriter(path) as w:
        w.add_topic("/tracker/points", POINT_CLOUD_TYPE)
        if tool:
            w.add_topic("/tool/pose", "geometry_msgs/msg/PoseStamped")
        for i, (t, n) in enumerate(zip(t_ns, widths)):
            cloud = np.zeros(n, TRACKED_DTYPE)
            cloud["x"] = np.linspace(-0.02, 0.02, n)
            cloud["y"] = 0.02
            # stamped with t, received in order (a tracker whose frames arrive late keeps their capture stamps)
            w.write("/tracker/points", m.encode_point_cloud((int(t) // 10**9, int(t) % 10**9), "world", cloud),
                    int(t_ns.min()) + i * 40_000_000)
        if tool:
            for t in (tool_t if tool_t is not None else t_ns):
                w.write("/tool/pose", m.encode_pose_stamped((int(t) // 10**9, int(t) % 10**9), "world", 0.0, 0.06, 0.0),
                        int(t))
    return path


@pytest.mark.parametrize("case,match", [
    ("no_points_topic", "has no points topic '/tracker/points'"),
    ("no_tool", "has no topic carrying a tool pose"),
    ("width", "cloud 2 has 4 points, the first had 3"),
    ("order", "observation stamps out of order: frame 3 at 1000000000066000000 ns is not after frame 2"),
    ("short", "2 observation frame(s): too short"),
    ("outside", "tracked point 0 at (0.2000, 0.0200) m is outside the tissue"),
    ("holdout", "--holdout 1.5: expected a fraction in [0, 1)"),
    ("unknown", "--fit 'stiffnes': expected a numeric simulation parameter"),
    ("nonempty", "exists and is not empty"),
])
def test_cli_bad_input(tmp_path, scene_image, capsys, case, match):
    t = 10**18 + np.arange(6, dtype=np.int64) * 33_000_000
    bag = tmp_path / "bag"
    extra: list[str] = []
    if case == "no_points_topic":
        with BagWriter(bag) as w:
            w.add_topic("/tool/pose", "geometry_msgs/msg/PoseStamped")
            w.write("/tool/pose", m.encode_pose_stamped((1, 0), "world", 0, 0.06, 0), 10**9)
    elif case == "no_tool":
        _cloud_bag(bag, t, [3] * 6, tool=False)
    elif case == "width":
        _cloud_bag(bag, t, [3, 3, 4, 3, 3, 3])
    elif case == "order":
        _cloud_bag(bag, t[[0, 1, 3, 2, 4, 5]], [3] * 6, tool_t=t)
    elif case == "short":
        _cloud_bag(bag, t[:2], [3] * 2)
    elif case == "outside":
        pts = np.zeros((6, 1, 2))
        pts[:, 0] = (0.2, 0.02)
        write_recording(bag, t, pts, t, np.tile([0.0, 0.06, 0.0], (6, 1)))
    else:
        _cloud_bag(bag, t, [3] * 6)
        extra = {"holdout": ["--holdout", "1.5"], "unknown": ["--fit", "stiffnes"], "nonempty": []}[case]
    out = tmp_path / "out" if case == "nonempty" else tmp_path / "new" / "deeper" / "out"
    if case == "nonempty":
        out.mkdir()
        (out / "keep.txt").write_text("mine")
    scene = _write_scene(tmp_path / "scene.yaml", scene_image)
    rc = cli(["fit", str(bag), "--points-topic", "/tracker/points", "--params", str(scene), "--out", str(out),
              "--no-progress", "--jobs", "1", *extra])
    err = capsys.readouterr().err
    assert rc == 2
    assert match in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    if case == "nonempty":
        assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    else:
        assert not (tmp_path / "new").exists()  # nor the directories above --out it would have made
    assert not list(tmp_path.rglob(".out.*")), "nothing half written"


def test_output_directory_has_the_mode_of_any_other(tmp_path):
    """The staging directory (tempfile.mkdtemp: 0700) becomes --out with an ordinary directory's mode."""
    import os
    import stat

    from tissue_sim_ros.experiments.fit import commit_outputs, staging_dir

    plain = tmp_path / "plain"
    plain.mkdir()
    out = tmp_path / "fit1"
    staging = staging_dir(out)
    commit_outputs(staging, out)
    assert stat.S_IMODE(os.stat(out).st_mode) == stat.S_IMODE(os.stat(plain).st_mode)  # was 0o700


def test_bench_fit_quick(tmp_path, capsys):
    assert cli(["bench", "fit", "--quick", "--jobs", "1", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "E within 5%:" in text and "fit wall time median" in text
    rows = (tmp_path / "fit.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[0].startswith("points,seed,steps")
    assert (tmp_path / "fit.png").stat().st_size > 0


def test_bench_fit_prints_no_nan_for_an_estimate_it_did_not_return():
    """``bench fit --quick`` printed "nu err +nan" when nu was not identifiable: the error of no estimate is "-"."""
    from tissue_sim_ros.bench.fit import _num

    assert _num(float("nan"), "+7.4f") == "      -" and _num(float("nan"), "+.4f") == "-"
    assert _num(None, "6.2f") == "     -" and _num(0.0123, "+7.4f") == "+0.0123"
