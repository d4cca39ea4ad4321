"""``tissue-sim envs evaluate``: the baselines' table (envs/policies.py): the expert and random policies over
seeded episodes of each task."""
from __future__ import annotations

import argparse
import csv
import dataclasses
from pathlib import Path

from tqdm import tqdm

from ...core.errors import InputError
from ...envs import ENVIRONMENTS, policies
from . import writable_dir

HELP = "success rates of the expert and random policies over seeded episodes"
DESCRIPTION = policies.__doc__
POLICIES = ("expert", "random")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default="all", help=f"a task ({', '.join(ENVIRONMENTS)}) or all (default)")
    parser.add_argument("--policy", default="all", choices=(*POLICIES, "all"), help="which baseline (default all)")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per task and policy (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="the first episode's seed; the others follow (default 0)")
    parser.add_argument("--out", default="out/envs", metavar="DIR",
                        help="writes baselines.csv (a row per task and policy) and episodes.csv (default out/envs)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym  # noqa: PLC0415

    envs = list(ENVIRONMENTS) if args.env == "all" else [args.env]
    if any(e not in ENVIRONMENTS for e in envs):
        raise InputError(f"--env {args.env!r}: expected all or one of {', '.join(ENVIRONMENTS)}")
    if args.episodes < 1:
        raise InputError(f"--episodes {args.episodes}: expected an integer >= 1")
    out = writable_dir(args.out)
    chosen = POLICIES if args.policy == "all" else (args.policy,)
    seeds = range(args.seed, args.seed + args.episodes)
    rows, episodes = [], []
    bar = tqdm(total=len(envs) * len(chosen) * args.episodes, desc="evaluate", unit="episode",
               disable=args.no_progress)
    for env_id in envs:
        env = gym.make(env_id)
        for name in chosen:
            policy = policies.make_expert(env) if name == "expert" else policies.RandomPolicy(env, seed=args.seed)
            bar.set_postfix_str(f"{env_id} {name}")
            res = policies.evaluate(env, policy, seeds, progress=lambda i, n: bar.update(1))
            rows.append({"env": env_id, "policy": name, **policies.summarise(res)})
            episodes += [{"env": env_id, "policy": name, **dataclasses.asdict(r)} for r in res]
        env.close()
    bar.close()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else ["n/a"]
    print(f"baselines over seeds {seeds.start}..{seeds.stop - 1} (load average {' '.join(load)}):")
    print(f"  {'env':<22} {'policy':<7} {'success':>8} {'any step':>9} {'final d [mm]':>13} {'peak F [N]':>11}")
    for r in rows:
        print(f"  {r['env']:<22} {r['policy']:<7} {r['success']:>8.0%} {r['success_any_step']:>9.0%} "
              f"{r['median_final_distance_mm']:>13.2f} {r['median_peak_force_N']:>11.3f}")
    for name, table in (("baselines.csv", rows), ("episodes.csv", episodes)):
        with (out / name).open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
    print(f"wrote: {out / 'baselines.csv'}, {out / 'episodes.csv'}")
    return 0
