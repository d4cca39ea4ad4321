"""Expert demonstrations as Minari datasets (Farama's format for offline RL), written under a directory of ours.

:func:`collect` runs the task's expert (:mod:`.policies`) for ``episodes`` seeded episodes (seeds ``seed``,
``seed + 1``, ...) through ``minari.DataCollector`` and writes the dataset ``tissuesim/<task>/expert-v0`` under
``out`` (Minari's datasets root is ``MINARI_DATASETS_PATH``, set to ``out`` for the call, so nothing goes to
``~/.minari``; the episodes are gathered as ``minari.DataCollector`` gathers them, without the jax that it needs
to do so, and written by ``minari.create_dataset_from_buffers``): observations (the Dict of each step), actions, rewards, terminations, truncations, every step's
``info`` and each episode's seed. Read it back with::

    import os, minari
    os.environ["MINARI_DATASETS_PATH"] = "DIR"          # the --out of tissue-sim envs collect
    dataset = minari.load_dataset("tissuesim/retract/expert-v0")

:func:`replay` checks a dataset: each episode's actions, stepped from ``reset(seed=its seed)`` in the environment
Minari recovers from the dataset, give the recorded observations bit for bit.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import gymnasium as gym
import numpy as np

from ..core.errors import InputError
from . import ENVIRONMENTS
from .policies import make_expert

DATASETS_ROOT = "MINARI_DATASETS_PATH"


def dataset_id(env_id: str, name: str = "expert") -> str:
    """``TissueSim/Retract-v0`` -> ``tissuesim/retract/expert-v0`` (Minari's namespace/env/name-version)."""
    task = env_id.split("/")[-1].split("-v")[0].lower()
    return f"tissuesim/{task}/{name}-v0"


def check_env_id(env_id: str) -> str:
    if env_id not in ENVIRONMENTS:
        raise InputError(f"--env {env_id!r}: expected one of {', '.join(ENVIRONMENTS)}")
    return env_id


@contextlib.contextmanager
def datasets_root(path: str | Path) -> Iterator[Path]:
    """Minari's datasets root set to ``path`` while inside (and put back after)."""
    old = os.environ.get(DATASETS_ROOT)
    os.environ[DATASETS_ROOT] = str(Path(path).resolve())
    try:
        yield Path(path)
    finally:
        if old is None:
            os.environ.pop(DATASETS_ROOT, None)
        else:
            os.environ[DATASETS_ROOT] = old


def collect(env_id: str, episodes: int, out: str | Path, *, seed: int = 0, env_kwargs: Mapping[str, Any] | None = None,
            overwrite: bool = False, progress: Callable[[int, int], None] | None = None,
            step_progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Record ``episodes`` expert episodes of ``env_id`` as a Minari dataset under ``out`` (module docstring).

    Returns a summary: the dataset id and path, episodes, steps, the expert's success rate. ``progress(i, n)``
    after each episode, ``step_progress()`` after each step. An existing dataset of the same id is an InputError
    unless ``overwrite``.
    """
    import minari  # noqa: PLC0415  (the envs extra: only this command needs it)

    check_env_id(env_id)
    if isinstance(episodes, bool) or int(episodes) != episodes or episodes < 1:
        raise InputError(f"--episodes {episodes!r}: expected an integer >= 1")
    did = dataset_id(env_id)
    out = Path(out)
    target = out / did
    if target.exists():
        if not overwrite:
            raise InputError(f"--out {str(out)!r} already holds {did}: expected a new directory, or --overwrite")
        shutil.rmtree(target)
    out.mkdir(parents=True, exist_ok=True)
    from minari.data_collector import EpisodeBuffer  # noqa: PLC0415

    env = gym.make(env_id, **dict(env_kwargs or {}))
    policy = make_expert(env)
    buffers, successes, steps = [], 0, 0
    for i in range(int(episodes)):
        obs, info = env.reset(seed=seed + i)
        observations = {k: [v] for k, v in obs.items()}
        infos = {k: [v] for k, v in info.items()}
        actions, rewards, terms, truncs = [], [], [], []
        done = False
        while not done:
            action = policy(obs)
            obs, reward, term, trunc, info = env.step(action)
            for k, v in obs.items():
                observations[k].append(v)
            for k, v in info.items():
                infos[k].append(v)
            actions.append(action)
            rewards.append(reward)
            terms.append(term)
            truncs.append(trunc)
            steps += 1
            done = term or trunc
            if step_progress is not None:
                step_progress()
        successes += bool(info["is_success"])
        # the buffer minari.DataCollector would have filled (it needs jax only to append to such trees)
        buffers.append(EpisodeBuffer(id=i, seed=seed + i, observations=observations, actions=actions,
                                     rewards=rewards, terminations=terms, truncations=truncs, infos=infos))
        if progress is not None:
            progress(i + 1, int(episodes))
    kind = type(env.unwrapped).__name__
    algorithm = ("model-predictive grasp controller (core/plan/control.py)" if kind != "ProbeEnv"
                 else "energy-ranked insertion planner (core/plan/insertion.py)")
    with datasets_root(out), warnings.catch_warnings():
        # minari asks for a permalink and an e-mail address, which a local dataset of a run has not
        warnings.filterwarnings("ignore", message=r"`(code_permalink|author_email)` is set to None")
        minari.create_dataset_from_buffers(
            dataset_id=did, buffer=buffers, env=env, eval_env=env.spec, algorithm_name=algorithm, author="tissue_sim_ros",
            description=f"{episodes} expert episodes of {env_id} (seeds {seed}..{seed + episodes - 1}), written by "
                        "tissue-sim envs collect", requirements=["tissue_sim_ros", "gymnasium>=1.0"])
    env.close()
    return {"dataset": did, "path": str(target), "episodes": int(episodes), "steps": steps,
            "expert success": successes / int(episodes)}


def replay(out: str | Path, did: str) -> dict[str, Any]:
    """Replay every episode of dataset ``did`` under ``out`` (module docstring): how many episodes and steps
    reproduced their observations bit for bit, and the first that did not."""
    import minari  # noqa: PLC0415

    with datasets_root(out):
        try:
            dataset = minari.load_dataset(did)
        except FileNotFoundError:
            raise InputError(f"{str(out)!r}: holds no dataset {did}; expected the --out of tissue-sim envs collect") \
                from None
        env = dataset.recover_environment()
        seeds = [m.get("seed") for m in dataset.storage.get_episode_metadata(range(dataset.total_episodes))]
        same, first_bad, steps = 0, None, 0
        for ep, s in zip(dataset.iterate_episodes(), seeds):
            obs, _ = env.reset(seed=None if s is None else int(s))
            ok = _equal(obs, ep.observations, 0)
            for k in range(len(ep.actions)):
                obs, *_ = env.step(ep.actions[k])
                ok = ok and _equal(obs, ep.observations, k + 1)
                steps += 1
            same += ok
            if not ok and first_bad is None:
                first_bad = ep.id
        env.close()
    return {"episodes": dataset.total_episodes, "reproduced": same, "steps": steps, "first mismatch": first_bad}


def _equal(obs: Mapping[str, np.ndarray], recorded: Mapping[str, np.ndarray], k: int) -> bool:
    return all(np.array_equal(obs[key], recorded[key][k]) for key in obs)
