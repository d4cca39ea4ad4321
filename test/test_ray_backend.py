"""--backend ray: the same sweeps on a real single-node Ray cluster bound to 127.0.0.1, the same numbers.

One private cluster for the module (``ray.init(address="local", ...)``, 2 CPUs,
no dashboard), shut down at the end. Every comparison is exact.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.sim.batch import rollout_batch
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.core.timing import trajectories as tr

ray = pytest.importorskip("ray", reason="the test extra installs ray (pip install '.[test]')")


@pytest.fixture(scope="module")
def cluster():
    from tissue_sim_ros.core.sim.backends import init_ray

    assert not ray.is_initialized()
    init_ray("local", num_cpus=2)
    yield ray
    ray.shutdown()


def _same(a, b) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def test_ray_actors_roll_out_bit_identical_to_serial(cluster):
    from tissue_sim_ros.core.sim.backends import RayRolloutPool, rollout_pool

    sim = build_simulation({"tool_length": 0.3, "contact_model": "projection"})
    traj = tr.experiment_b(sim.tool, sim.params.dt, -25.0, speed=0.004, distance=0.12)
    for pose, twist in list(traj.steps(sim.params.dt))[:20]:  # from a live, deformed state
        sim.step(pose, twist)
    cands = [tr.experiment_b(sim.tool, sim.params.dt, a, speed=0.004, distance=0.12) for a in (-10.0, -30.0, -40.0)]
    serial = rollout_batch(sim, cands, final_state=True)
    with rollout_pool(sim, 2, backend="ray") as pool:
        assert isinstance(pool, RayRolloutPool) and len(set(pool.pids)) == 2
        res = pool.run(sim.snapshot(), cands, final_state=True)
    assert res.workers == 2
    for s, r in zip(serial.candidates, res.candidates):
        assert s.metrics() == r.metrics()
        assert np.array_equal(s.energy, r.energy)
        assert np.array_equal(s.final_state.particle_q, r.final_state.particle_q)


def test_plan_on_ray_equals_the_local_backend(cluster, tmp_path, capsys):
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.experiments.plan import plan

    args = ({"tool_length": 0.3}, [-10.0, -30.0], [0.002], tr.B_TARGET, 0.06)
    local = plan(*args, jobs=1, progress=False)
    remote = plan(*args, jobs=2, progress=False, backend="ray")
    drop = ("wall_s",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in local] == \
        [{k: v for k, v in r.items() if k not in drop} for r in remote]
    assert main(["plan", "--angles", "-10", "-30", "20", "--speeds", "0.002", "--distance", "0.04", "--jobs", "2",
                 "--backend", "ray", "--out", str(tmp_path), "--no-progress"]) == 0
    assert "on 2 Ray actors" in capsys.readouterr().out


def test_stability_runs_on_ray_as_locally(cluster):
    from tissue_sim_ros.bench.stability import RunConfig, make_mesh, run_one
    from tissue_sim_ros.core.sim.backends import map_calls

    mesh = make_mesh("regular")
    configs = [RunConfig("xpbd", "projection", 0.01, 1.0, 0.01, "regular", n_steps=6),
               RunConfig("pbd", "paper", 0.01, 1000.0, 0.2, "regular", n_steps=6)]
    local = [run_one(c, mesh) for c in configs]
    remote = map_calls(run_one, [(c, mesh) for c in configs], backend="ray")
    for a, b in zip(local, remote):
        assert a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a), (a, b)


def test_a_bad_backend_is_refused():
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.core.errors import InputError
    from tissue_sim_ros.core.sim.backends import check_backend

    with pytest.raises(SystemExit) as exc:  # argparse: one usage line, exit 2
        main(["plan", "--backend", "spark", "--out", "/tmp/x"])
    assert exc.value.code == 2
    with pytest.raises(InputError, match="expected one of local, ray"):
        check_backend("spark")


# --------------------------------------------------------------------------- tune and fit on Ray

#: measured times: they differ run to run, every other column must be equal
TIMES = ("ms_per_step", "newton_ms", "wall_s_total")


def _untimed(rows):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


def test_tune_constraints_on_ray_equals_the_local_backend(cluster):
    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.tune.settings import tune

    values = resolve_config().flat()
    # a budget no setting exceeds: which counts run depends on the errors only, not on the times
    args = (values, 0.05, 1e9, [0.1], 3, (1, 10), ("pbd", "xpbd"))
    _, local = tune(*args)
    _, remote = tune(*args, jobs=2, backend="ray")
    assert len(local) >= 3 and len(local) == len(remote)
    for a, b in zip(_untimed(local), _untimed(remote)):
        assert a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a), (a, b)


def test_tune_material_runs_on_ray_as_locally(cluster):
    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.tune import material as tm

    cfg = resolve_config(params_file="config/scenes/liver_probe.yaml")
    press = tm.press_point(cfg.replace(spacing=0.008), 0.003)
    runs = [(tm.with_setting(tm.mesh_config(cfg, press, h, g), (1, 20, 1e-2)), press)
            for h, g in ((0.008, 0.0), (0.008, 0.004))]
    local = tm.rest_runs(runs)
    remote = tm.rest_runs(runs, jobs=2, backend="ray")
    assert local[0]["particles"] != local[1]["particles"]  # two different meshes
    for a, b in zip(local, remote):
        assert a.keys() == b.keys()
        for k in a:
            if k != "solve_ms":
                assert np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k], k


def test_fit_on_ray_equals_the_local_backend(cluster, tmp_path):
    from tissue_sim_ros.experiments import fit as fitcli
    from tissue_sim_ros.experiments import fit_scene as fs

    image = fs.write_scene_image(tmp_path / "scene.png")
    syn = fs.synthesize(fs.scene_params(image, spacing=0.008, **fs.TRUTH), n_points=8, noise=5e-4, seed=2,
                        duration=0.4)
    from tissue_sim_ros.core.fit.tracking import Recording

    rec = Recording(syn.t_ns, syn.points, syn.tool_t_ns, syn.tool_pose, source="test")
    setup = fitcli.prepare(rec, fs.scene_params(image, spacing=0.01), ["young_modulus", "poisson_ratio"],
                           holdout=0.2)
    kw = {"max_evals": 3, "slices": 0, "mesh_check": False}
    local = fitcli.run_fit(setup, jobs=1, **kw)
    remote = fitcli.run_fit(setup, jobs=2, backend="ray", **kw)
    assert remote.n_rollouts == local.n_rollouts > 0
    for name in ("young_modulus", "poisson_ratio"):
        a, b = local.estimate(name), remote.estimate(name)
        assert (a.value, a.sigma, a.low95, a.high95) == (b.value, b.sigma, b.low95, b.high95)
    assert local.rms_fit_mm == remote.rms_fit_mm and local.rms_holdout_mm == remote.rms_holdout_mm


@pytest.mark.parametrize("argv", [["tune", "--tolerance", "0.1", "--budget-ms", "1", "--backend", "spark"],
                                  ["fit", "--demo", "--out", "/tmp/x", "--backend", "spark"],
                                  ["bench", "fit", "--backend", "spark"]])
def test_every_sweep_declares_the_backend_options(argv, capsys):
    from tissue_sim_ros.cli import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and "invalid choice: 'spark'" in capsys.readouterr().err


def test_a_bad_jobs_count_is_one_line(capsys):
    from tissue_sim_ros.cli import main

    assert main(["tune", "--tolerance", "0.1", "--budget-ms", "1", "--jobs", "0"]) == 2
    assert "--jobs 0: expected at least 1 worker" in capsys.readouterr().err


def test_the_cluster_keeps_its_files_in_the_suites_own_directory(cluster):
    """``make test`` left a ``/tmp/ray/session_*`` behind on every run: the suite's clusters write under its own
    temporary directory (test/conftest.py), which the session removes at its end."""
    import os
    from pathlib import Path

    from ray._private import worker

    session = Path(worker._global_node.get_session_dir_path()).resolve()
    root = Path(os.environ["RAY_TMPDIR"]).resolve()
    assert root != Path("/tmp") and root in session.parents, (session, root)
