"""Learning environments: the tissue tasks as Gymnasium environments, and their expert policies and datasets.

Importing this package registers the tasks with Gymnasium, so either of these works::

    import gymnasium as gym
    import tissue_sim_ros.envs                                   # registers TissueSim/*
    env = gym.make("TissueSim/Retract-v0", render_mode="rgb_array")
    env = gym.make("tissue_sim_ros.envs:TissueSim/Retract-v0")   # imports this package itself

* ``TissueSim/Retract-v0`` (:mod:`.retract`): grasp the retraction flap and bring a point of it to a goal;
* ``TissueSim/Probe-v0`` (:mod:`.probe`): the paper's experiment b as a task: bring the tool tip to a target
  at the lower tissue through the gap, paying the tissue's implicit Euler energy and the reaction force;
* ``TissueSim/Shape-v0`` (:mod:`.shape`): grasp the flap and bring three of its points to a target shape.

The environments are built on the core alone (no ROS, no Matplotlib); :mod:`.policies` has the expert (the
model-predictive controller of :mod:`~tissue_sim_ros.core.plan.control`, the insertion planner of
:mod:`~tissue_sim_ros.core.plan.insertion`) and random policies, :mod:`.datasets` records Minari datasets.
This layer imports only the core; the CLI and the benchmarks import it (docs/envs.md).
"""
from __future__ import annotations

import gymnasium as gym

#: id -> (entry point, steps per episode)
ENVIRONMENTS = {
    "TissueSim/Retract-v0": ("tissue_sim_ros.envs.retract:RetractEnv", 300),
    "TissueSim/Probe-v0": ("tissue_sim_ros.envs.probe:ProbeEnv", 300),
    "TissueSim/Shape-v0": ("tissue_sim_ros.envs.shape:ShapeEnv", 300),
}

for _id, (_entry, _steps) in ENVIRONMENTS.items():
    if _id not in gym.registry:  # importing twice (a reload, a worker) registers once
        gym.register(id=_id, entry_point=_entry, max_episode_steps=_steps)

__all__ = ["ENVIRONMENTS"]
