"""--backend ray: the same sweeps on a real single-node Ray cluster bound to 127.0.0.1, the same numbers.

One private cluster for the module (``ray.init(address="local", ...)``, 2 CPUs,
no dashboard), shut down at the end. Every comparison is exact.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.batch import rollout_batch
from tissue_sim_ros.core.scene import build_simulation
from tissue_sim_ros.experiments import trajectories as tr

ray = pytest.importorskip("ray", reason="the test extra installs ray (pip install '.[test]')")


@pytest.fixture(scope="module")
def cluster():
    from tissue_sim_ros.core.backends import init_ray

    assert not ray.is_initialized()
    init_ray("local", num_cpus=2)
    yield ray
    ray.shutdown()


def _same(a, b) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def test_ray_actors_roll_out_bit_identical_to_serial(cluster):
    from tissue_sim_ros.core.backends import RayRolloutPool, rollout_pool

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
    from tissue_sim_ros.core.backends import map_calls

    mesh = make_mesh("regular")
    configs = [RunConfig("xpbd", "projection", 0.01, 1.0, 0.01, "regular", n_steps=6),
               RunConfig("pbd", "paper", 0.01, 1000.0, 0.2, "regular", n_steps=6)]
    local = [run_one(c, mesh) for c in configs]
    remote = map_calls(run_one, [(c, mesh) for c in configs], backend="ray")
    for a, b in zip(local, remote):
        assert a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a), (a, b)


def test_a_bad_backend_is_refused():
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.core.backends import check_backend
    from tissue_sim_ros.core.errors import InputError

    with pytest.raises(SystemExit) as exc:  # argparse: one usage line, exit 2
        main(["plan", "--backend", "spark", "--out", "/tmp/x"])
    assert exc.value.code == 2
    with pytest.raises(InputError, match="expected one of local, ray"):
        check_backend("spark")
