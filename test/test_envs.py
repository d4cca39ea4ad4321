"""The learning environments (tissue_sim_ros.envs): Gymnasium's checker, seeded episodes bit for bit, vector envs,
goal-conditioned rewards, randomisation, rendering, the experts, Minari datasets and the commands.

Small episodes only (tens of steps; the expert's Retract episode is the longest, ~1 s): the success tables over
100 seeds are ``tissue-sim envs evaluate`` and the speeds ``tissue-sim bench envs`` (docs/envs.md).
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import tissue_sim_ros.envs  # noqa: E402, F401  (registers the tasks)
from tissue_sim_ros.cli import main  # noqa: E402
from tissue_sim_ros.core.errors import InputError  # noqa: E402
from tissue_sim_ros.envs import ENVIRONMENTS  # noqa: E402
from tissue_sim_ros.envs.policies import RandomPolicy, expert_action, make_expert, run_episode  # noqa: E402

IDS = list(ENVIRONMENTS)


@pytest.fixture(scope="module")
def envs():
    """One environment of each task, shared (building one meshes its scene and warms the kernels)."""
    made = {i: gym.make(i, render_mode="rgb_array") for i in IDS}
    yield made
    for e in made.values():
        e.close()


def _episode(env, seed: int, steps: int, actions_seed: int = 7, options=None):
    obs, info = env.reset(seed=seed, options=options)
    rng = np.random.default_rng(actions_seed)
    out = [obs]
    infos = [info]
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        out.append(obs)
        infos.append((r, info))
    return out, infos


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_passes(env_id, envs):
    from gymnasium.utils.env_checker import check_env

    env = envs[env_id].unwrapped
    with pytest.warns(UserWarning):  # the checker's note on unbounded Box observations (positions, forces): as meant
        check_env(env, skip_render_check=False)
    # each mode this machine offers: rgb_array always, human where there is a display
    assert "rgb_array" in env.metadata["render_modes"]


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_episode_repeats_bit_for_bit(env_id, envs):
    env = envs[env_id]
    a, ia = _episode(env, 5, 25)
    _episode(env, 6, 10)  # another episode between: nothing carries over
    b, ib = _episode(env, 5, 25)
    for x, y in zip(a, b):
        for k in x:
            assert np.array_equal(x[k], y[k]), k
    assert [r for r, _ in ia[1:]] == [r for r, _ in ib[1:]]
    fresh = gym.make(env_id)  # and a new environment gives the same episode
    c, _ = _episode(fresh, 5, 25)
    assert all(np.array_equal(x[k], y[k]) for x, y in zip(a, c) for k in x)
    other, _ = _episode(env, 8, 1)
    assert not np.array_equal(other[0]["desired_goal"], a[0]["desired_goal"])  # the goal is drawn per episode


def test_vector_envs_equal_single_envs():
    seeds = [3, 4]
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (12, 2, 3)).astype(np.float32)
    ref = []
    for j, s in enumerate(seeds):
        env = gym.make("TissueSim/Retract-v0")
        o, _ = env.reset(seed=s)
        obs = [o["observation"]]
        for a in actions[:, j]:
            o, *_ = env.step(a)
            obs.append(o["observation"])
        ref.append(obs)
    ref = np.stack([np.array(r) for r in ref], axis=1)
    for cls in (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv):
        venv = cls([lambda: gym.make("TissueSim/Retract-v0") for _ in seeds])
        try:
            o, info = venv.reset(seed=seeds)
            obs = [o["observation"]]
            for a in actions:
                o, r, te, tr, info = venv.step(a)
                obs.append(o["observation"])
        finally:
            venv.close()
        assert np.array_equal(np.array(obs), ref), cls.__name__
        assert info["energy"].shape == (2,)


def test_make_by_module_path_without_importing_first():
    code = ("import gymnasium as gym\n"
            "env = gym.make('tissue_sim_ros.envs:TissueSim/Retract-v0')\n"
            "obs, info = env.reset(seed=0)\n"
            "print(sorted(obs), env.action_space.shape, env.spec.max_episode_steps)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['achieved_goal', 'desired_goal', 'observation'] (3,) 300"


@pytest.mark.parametrize("env_id", IDS)
def test_compute_reward_is_vectorised_for_relabelling(env_id, envs):
    env = envs[env_id].unwrapped
    obs, info = env.reset(seed=1)
    obs, r, *_, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert r == env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
    ag = np.repeat(obs["achieved_goal"][None], 4, axis=0)
    dg = np.repeat(obs["desired_goal"][None], 4, axis=0)
    dg[1] = ag[1]  # relabelled: the goal is where the point got
    batch = env.compute_reward(ag, dg, [info] * 4)
    assert batch.shape == (4,)
    assert batch[0] == pytest.approx(r, rel=1e-6) and batch[1] > batch[0]
    sparse = gym.make(env_id, reward_type="sparse").unwrapped
    sparse.reset(seed=1)
    rs = sparse.compute_reward(ag, dg, {k: np.full(4, v) for k, v in info.items()})
    penalty = rs[1]  # Probe also charges the energy and force in the sparse reward
    assert rs[0] == pytest.approx(penalty - 1.0) and penalty <= 0.0


def test_observation_layout_and_info(envs):
    env = envs["TissueSim/Retract-v0"].unwrapped
    obs, info = env.reset(seed=2)
    k = env.point_w.shape[0]
    vec = obs["observation"]
    assert vec.shape == (2 * k + 8,) and vec.dtype == np.float32
    assert np.allclose(vec[:2 * k].reshape(k, 2), env.points(), atol=1e-7)
    assert np.allclose(vec[2 * k:2 * k + 3], (*env.tip, 0.0))
    assert vec[2 * k + 3] == pytest.approx(env.jaw_open)  # starts open
    assert set(info) >= {"is_success", "distance", "energy", "energy_inertial", "energy_strain", "energy_attach",
                         "force", "penetration", "converged", "diverged", "grasped"}
    # the action's limits: +1 moves the tip max_speed * dt, the workspace clips it
    tip = env.tip.copy()
    env.step(np.array([1.0, -1.0, 1.0], dtype=np.float32))
    assert np.allclose(env.tip - tip, [env.max_speed * env.dt, -env.max_speed * env.dt])
    with pytest.raises(InputError, match="expected 3 finite values"):
        env.step(np.array([np.nan, 0.0, 0.0]))


def test_randomisation_and_noise_are_seeded():
    env = gym.make("TissueSim/Retract-v0", young_modulus=(3000.0, 8000.0), damping=(5.0, 15.0),
                   point_noise=0.0005).unwrapped
    o1, _ = env.reset(seed=11)
    m1 = dict(env.episode_material)
    o2, _ = env.reset(seed=11)
    assert env.episode_material == m1 and np.array_equal(o1["observation"], o2["observation"])
    env.reset(seed=12)
    assert env.episode_material["young_modulus"] != m1["young_modulus"]
    assert 3000.0 <= m1["young_modulus"] <= 8000.0 and env.sim.params.young_modulus == env.episode_material[
        "young_modulus"]
    clean = env.points()
    assert not np.allclose(o1["observation"][:clean.size], clean.ravel(), atol=1e-6)  # noisy points
    o3, _ = env.reset(seed=11, options={"point_noise": 0.0, "young_modulus": 5000.0, "goal": (0.045, 0.03)})
    assert env.episode_material["young_modulus"] == 5000.0
    assert np.allclose(o3["desired_goal"], (0.045, 0.03))
    with pytest.raises(InputError, match="reset option 'young_modulos'"):
        env.reset(options={"young_modulos": 1.0})
    with pytest.raises(InputError, match="poisson_ratio"):
        gym.make("TissueSim/Retract-v0", poisson_ratio=(0.3, 0.6))
    with pytest.raises(InputError, match="material 'constraints'"):
        gym.make("TissueSim/Probe-v0", young_modulus=1e4)


def test_render_modes(envs):
    env = envs["TissueSim/Shape-v0"]
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (320, 480, 3) and frame.dtype == np.uint8
    assert (frame != 255).any(axis=2).mean() > 0.05  # tissue and tool drawn
    # yellow goal rings
    assert ((frame[..., 0] > 200) & (frame[..., 1] > 150) & (frame[..., 2] < 60)).any()
    import os

    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        with pytest.raises(InputError, match="render_mode='human': no display"):
            gym.make("TissueSim/Retract-v0", render_mode="human")


def test_random_policy_and_expert_on_retract(envs):
    env = envs["TissueSim/Retract-v0"]
    rand = run_episode(env, RandomPolicy(env, seed=0), seed=0)
    assert rand.steps == 300 and not rand.success
    expert = run_episode(env, make_expert(env), seed=0)
    assert expert.success, expert
    # expert_action keeps one expert per environment and restarts it each episode
    obs, _ = env.reset(seed=1)
    a = expert_action(env)
    assert a.shape == (3,) and np.all(np.abs(a) <= 1.0)


def test_probe_expert_plans_by_energy(envs):
    env = envs["TissueSim/Probe-v0"]
    res = run_episode(env, make_expert(env), seed=0)
    assert res.success and res.energy > 0
    assert env.unwrapped.baseline.shape == (300,)


def test_collect_writes_a_minari_dataset_that_replays(tmp_path, capsys):
    pytest.importorskip("minari")
    out = tmp_path / "data"
    assert main(["envs", "collect", "--env", "TissueSim/Retract-v0", "--episodes", "2", "--out", str(out),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "replayed: 2 of 2 episodes reproduce their observations bit for bit" in text
    import minari

    from tissue_sim_ros.envs.datasets import datasets_root

    with datasets_root(out):
        ds = minari.load_dataset("tissuesim/retract/expert-v0")
        assert ds.total_episodes == 2 and ds.total_steps == 600
        ep = next(ds.iterate_episodes())
        assert ep.observations["observation"].shape == (301, 40) and ep.actions.shape == (300, 3)
    assert main(["envs", "collect", "--episodes", "1", "--out", str(out), "--no-progress"]) == 2  # exists
    assert "already holds tissuesim/retract/expert-v0" in capsys.readouterr().err


def test_commands_refuse_bad_input_in_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for argv, expected in ((["envs", "collect", "--env", "Nope-v0", "--out", str(tmp_path)], "--env 'Nope-v0'"),
                           (["envs", "collect", "--out", str(blocker)], "exists and is not a directory"),
                           (["envs", "collect", "--episodes", "0", "--out", str(tmp_path)], "--episodes 0"),
                           (["envs", "evaluate", "--env", "x", "--out", str(tmp_path)], "--env 'x'")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert expected in err and err.count("\n") == 1, err


def test_evaluate_writes_the_table(tmp_path, capsys):
    assert main(["envs", "evaluate", "--env", "TissueSim/Probe-v0", "--policy", "random", "--episodes", "1",
                 "--out", str(tmp_path), "--no-progress"]) == 0
    assert "TissueSim/Probe-v0" in capsys.readouterr().out
    rows = (tmp_path / "baselines.csv").read_text().splitlines()
    assert rows[0].startswith("env,policy,episodes,success") and len(rows) == 2


def test_bench_envs_writes_its_table_and_chart(tmp_path, capsys):
    """The benchmark's plumbing on one task, one repeat (its numbers are docs/envs.md's, from the full run)."""
    from tissue_sim_ros.bench import envs as bench

    rows = bench.run(tmp_path, envs=["TissueSim/Probe-v0"], vector=(1, 2), vector_steps=5, repeats=1, progress=False)
    assert [(r["mode"], r["envs"]) for r in rows] == [("env", 1), ("sync", 1), ("sync", 2), ("async", 1),
                                                      ("async", 2)]
    assert rows[0]["steps_per_s"] > 0 and rows[0]["sim_steps_per_s"] > 0
    assert (tmp_path / "envs_bench.csv").exists() and (tmp_path / "envs_bench.png").stat().st_size > 10_000
    assert "overhead" in capsys.readouterr().out
