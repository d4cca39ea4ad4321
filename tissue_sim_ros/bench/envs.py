"""``tissue-sim bench envs``: the learning environments' steps per second, single and vectorised, beside the plain
``Simulation.step`` of the same scene.

For each task (and each ``--spacings`` of Retract-v0: the mesh spacing is the environment's speed option):

* ``env``: one environment, one core: an episode of the expert's actions (recorded first, untimed, so the tissue is
  grasped, pulled, pressed as in real use), replayed ``--repeats`` times from ``reset(seed=0)``; steps/s of each
  repeat, the median reported, with the median single step [us];
* ``sim``: the same episode's tool poses and jaw angles replayed on a plain ``Simulation`` of the environment's
  scene (``Simulation.step(pose, jaw=...)``, nothing else), alternating with the env's repeats: the rate the
  wrapper is measured against, and ``overhead``, the median over the repeats of sim rate / env rate - 1 (the
  wrapper's share: the Gymnasium wrappers, action scaling, tracked points, reward, info);
* ``sync N``, ``async N``: ``gymnasium.vector.SyncVectorEnv`` / ``AsyncVectorEnv`` of N environments (N in
  ``--vector``, default 1 2 4 8) stepped with uniform random actions for ``--vector-steps`` steps (autoreset
  included), environment steps per second summed over the N (median of ``--repeats``); Async runs its N workers
  on the machine's cores (two here).

Writes ``envs_bench.csv`` (a row per task and mode) and ``envs_bench.png`` (the rates as bars and against N) and
prints the table with the load average. Numbers and their load are in docs/envs.md.
"""
from __future__ import annotations

import csv
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.sim.simulation import Simulation


def _load() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def expert_episode(env: Any, seed: int = 0) -> tuple[list[np.ndarray], list[tuple[ToolPose, float | None]]]:
    """The expert's actions over one episode, and the tool commands (pose, jaw) each produced."""
    from ..envs.policies import make_expert  # noqa: PLC0415

    policy = make_expert(env)
    obs, _ = env.reset(seed=seed)
    actions, commands = [], []
    done = False
    e = env.unwrapped
    while not done:
        a = policy(obs)
        obs, _, term, trunc, _ = env.step(a)
        actions.append(a)
        commands.append((e.pose(), e.jaw if e.jaw_open > 0 else None))
        done = term or trunc
    return actions, commands


def time_env(env: Any, actions: Sequence[np.ndarray]) -> tuple[float, list[float]]:
    """One replay of ``actions`` from ``reset(seed=0)`` (the reset untimed): steps/s and each step [s]."""
    env.reset(seed=0)
    steps = []
    t0 = time.perf_counter()
    for a in actions:
        t = time.perf_counter()
        env.step(a)
        steps.append(time.perf_counter() - t)
    return len(actions) / (time.perf_counter() - t0), steps


def time_sim(sim: Simulation, start: Any, commands: Sequence[tuple[ToolPose, float | None]]) -> tuple[float, list[float]]:
    """The same commands on a plain Simulation from the episode's start snapshot: steps/s and each step [s]."""
    sim.restore(start)
    steps = []
    t0 = time.perf_counter()
    for pose, jaw in commands:
        t = time.perf_counter()
        sim.step(pose, jaw=jaw)
        steps.append(time.perf_counter() - t)
    return len(commands) / (time.perf_counter() - t0), steps


def time_pair(env: Any, actions: Sequence[np.ndarray], commands: Sequence[tuple[ToolPose, float | None]],
              repeats: int) -> dict[str, float]:
    """The environment and the plain step, alternating repeat by repeat (a change of the machine's load falls on
    both alike): median steps/s and median step of each, and the overhead, the median over the repeats of
    sim rate / env rate - 1."""
    e = env.unwrapped
    sim = Simulation.from_config(e.config, mesh=e.mesh)
    sim.warm_up()
    e.reset(seed=0)  # the episode's first state and tool pose
    start = e.sim.snapshot()
    env_rates, sim_rates, env_steps, sim_steps = [], [], [], []
    for _ in range(repeats):
        rate, steps = time_env(env, actions)
        env_rates.append(rate)
        env_steps += steps
        rate, steps = time_sim(sim, start, commands)
        sim_rates.append(rate)
        sim_steps += steps
    return {"steps_per_s": float(np.median(env_rates)), "median_step_us": 1e6 * float(np.median(env_steps)),
            "sim_steps_per_s": float(np.median(sim_rates)), "sim_median_step_us": 1e6 * float(np.median(sim_steps)),
            "overhead": float(np.median(np.array(sim_rates) / np.array(env_rates))) - 1.0}


def time_vector(env_id: str, kind: str, n: int, steps: int, repeats: int, kwargs: dict) -> list[float]:
    """Environment steps/s (summed over the ``n`` environments) of a ``kind`` ("sync"/"async") vector env."""
    import gymnasium as gym  # noqa: PLC0415

    cls = gym.vector.SyncVectorEnv if kind == "sync" else gym.vector.AsyncVectorEnv
    venv = cls([lambda: gym.make(env_id, **kwargs) for _ in range(n)])
    try:
        venv.action_space.seed(0)
        rates = []
        for r in range(repeats):
            venv.reset(seed=list(range(r * n, (r + 1) * n)))
            acts = [venv.action_space.sample() for _ in range(steps)]
            t0 = time.perf_counter()
            for a in acts:
                venv.step(a)
            rates.append(n * steps / (time.perf_counter() - t0))
    finally:
        venv.close()
    return rates


def run(out: str | Path, *, envs: Sequence[str] | None = None, spacings: Sequence[float] = (0.004,),
        vector: Sequence[int] = (1, 2, 4, 8), vector_steps: int = 200, repeats: int = 5,
        progress: bool = True) -> list[dict[str, Any]]:
    """Run the benchmark (module docstring); returns the rows it wrote."""
    import gymnasium as gym  # noqa: PLC0415

    from ..envs import ENVIRONMENTS  # noqa: PLC0415

    envs = list(ENVIRONMENTS) if not envs else list(envs)
    for e in envs:
        if e not in ENVIRONMENTS:
            raise InputError(f"--envs {e!r}: expected some of {', '.join(ENVIRONMENTS)}")
    if repeats < 1 or vector_steps < 1 or any(n < 1 for n in vector):
        raise InputError(f"--repeats {repeats}, --vector-steps {vector_steps}, --vector {list(vector)}: expected "
                         "integers >= 1")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = [(e, {}) for e in envs]
    if "TissueSim/Retract-v0" in envs:
        cases += [("TissueSim/Retract-v0", {"spacing": float(s)}) for s in spacings]
    rows: list[dict[str, Any]] = []
    for env_id, kwargs in cases:
        env = gym.make(env_id, **kwargs)
        label = env_id + (f" spacing {kwargs['spacing'] * 1e3:g} mm" if kwargs else "")
        info = env.unwrapped.describe()
        actions, commands = expert_episode(env)
        base = {"task": label, "particles": info["particles"], "method": info["method"], "load": _load()}
        rows.append({**base, "mode": "env", "envs": 1, **time_pair(env, actions, commands, repeats)})
        if progress:
            print(f"  {label}: env {rows[-1]['steps_per_s']:.0f} steps/s, sim {rows[-1]['sim_steps_per_s']:.0f} "
                  f"steps/s", flush=True)
        env.close()
        for kind in ("sync", "async"):
            for n in vector:
                rates = time_vector(env_id, kind, n, vector_steps, repeats, kwargs)
                rows.append({**base, "mode": kind, "envs": n, "steps_per_s": float(np.median(rates)),
                             "median_step_us": float("nan"), "sim_steps_per_s": float("nan"),
                             "sim_median_step_us": float("nan"), "overhead": float("nan"), "load": _load()})
                if progress:
                    print(f"  {label}: {kind} {n}: {rows[-1]['steps_per_s']:.0f} steps/s", flush=True)
    path = out / "envs_bench.csv"
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    _print_table(rows)
    _plot(rows, out / "envs_bench.png", vector)
    print(f"wrote: {path}, {out / 'envs_bench.png'}")
    return rows


def _print_table(rows: list[dict[str, Any]]) -> None:
    print(f"environment steps per second (median of repeats; load average now {_load()}):")
    print(f"  {'task':<38} {'particles':>9} {'env':>8} {'sim':>8} {'overhead':>9} {'env step':>9} {'sim step':>9}")
    for r in rows:
        if r["mode"] == "env":
            print(f"  {r['task']:<38} {r['particles']:>9} {r['steps_per_s']:>8.0f} {r['sim_steps_per_s']:>8.0f} "
                  f"{r['overhead']:>9.1%} {r['median_step_us']:>7.0f}us {r['sim_median_step_us']:>7.0f}us")
    print("  vectorised (random actions, autoreset; steps/s summed over the environments):")
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    ns = sorted({r["envs"] for r in rows if r["mode"] != "env"})
    print(f"  {'task':<38} {'mode':<6} " + " ".join(f"{'N=' + str(n):>8}" for n in ns))
    for t in tasks:
        for kind in ("sync", "async"):
            by_n = {r["envs"]: r["steps_per_s"] for r in rows if r["task"] == t and r["mode"] == kind}
            print(f"  {t:<38} {kind:<6} " + " ".join(f"{by_n.get(n, float('nan')):>8.0f}" for n in ns))


def _plot(rows: list[dict[str, Any]], path: Path, vector: Sequence[int]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(13, 4.8))
    single = [next(r for r in rows if r["task"] == t and r["mode"] == "env") for t in tasks]
    x = np.arange(len(tasks))
    ax0.bar(x - 0.2, [r["sim_steps_per_s"] for r in single], 0.4, label="Simulation.step", color="#9e9e9e")
    ax0.bar(x + 0.2, [r["steps_per_s"] for r in single], 0.4, label="env.step", color="#c62828")
    for i, r in enumerate(single):
        ax0.text(i + 0.2, r["steps_per_s"], f"+{r['overhead']:.0%}", ha="center", va="bottom", fontsize=8)
    ax0.axhline(2000, color="k", ls=":", lw=1)
    ax0.set_xticks(x, [t.replace("TissueSim/", "").replace(" spacing", "\n") for t in tasks], fontsize=8)
    ax0.set_ylabel("steps per second (one core)")
    ax0.set_title("One environment: the wrapper's overhead over the plain step", fontsize=10)
    ax0.legend(fontsize=8)
    colours = plt.get_cmap("tab10")
    for i, t in enumerate(tasks):
        for kind, ls in (("sync", "--"), ("async", "-")):
            pts = sorted((r["envs"], r["steps_per_s"]) for r in rows if r["task"] == t and r["mode"] == kind)
            if pts:
                ax1.plot(*zip(*pts), ls=ls, marker="o", color=colours(i),
                         label=f"{t.replace('TissueSim/', '')} {kind}")
    ax1.set_xscale("log", base=2)
    ax1.set_xticks(list(vector), [str(n) for n in vector])
    ax1.set_xlabel("environments in the vector env")
    ax1.set_ylabel("environment steps per second (all)")
    ax1.set_title(f"Vectorised (random actions), 2 cores; load {rows[-1]['load']}", fontsize=10)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
