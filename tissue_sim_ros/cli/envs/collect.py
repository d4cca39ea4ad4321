"""``tissue-sim envs collect``: the command line of envs/datasets.py (expert episodes as a Minari dataset)."""
from __future__ import annotations

import argparse

from tqdm import tqdm

from ...core.errors import InputError
from ...envs import ENVIRONMENTS, datasets
from . import writable_dir

HELP = "record a task's expert episodes as a Minari dataset (offline RL)"
DESCRIPTION = datasets.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default="TissueSim/Retract-v0", help=f"the task: {', '.join(ENVIRONMENTS)} "
                        "(default TissueSim/Retract-v0)")
    parser.add_argument("--episodes", type=int, default=20, help="episodes to record (default 20)")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory the dataset is written under "
                        "(Minari's datasets root for this call; load it with MINARI_DATASETS_PATH=DIR)")
    parser.add_argument("--seed", type=int, default=0, help="the first episode's seed; the others follow (default 0)")
    parser.add_argument("--spacing", type=float, default=None, metavar="M",
                        help="the task's mesh spacing [m] (default: the scene's)")
    parser.add_argument("--overwrite", action="store_true", help="replace a dataset of the same id under DIR")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip replaying the dataset's actions against its observations after writing it")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    datasets.check_env_id(args.env)
    if args.episodes < 1:
        raise InputError(f"--episodes {args.episodes}: expected an integer >= 1")
    out = writable_dir(args.out)
    kwargs = {} if args.spacing is None else {"spacing": args.spacing}
    limit = ENVIRONMENTS[args.env][1]
    bar = tqdm(total=args.episodes * limit, desc=f"collect {args.env}", unit="step", disable=args.no_progress)

    def episode_done(i: int, n: int) -> None:
        bar.set_postfix_str(f"episode {i}/{n}")
        bar.total = bar.n + (n - i) * limit  # an episode that ended early shortens the bar
        bar.refresh()

    summary = datasets.collect(args.env, args.episodes, out, seed=args.seed, env_kwargs=kwargs,
                               overwrite=args.overwrite, progress=episode_done, step_progress=lambda: bar.update(1))
    bar.close()
    print("collect:")
    for k, v in summary.items():
        print(f"  {k}: {v}")
    if not args.no_verify:
        check = datasets.replay(out, summary["dataset"])
        print(f"  replayed: {check['reproduced']} of {check['episodes']} episodes reproduce their observations "
              "bit for bit")
        if check["reproduced"] != check["episodes"]:
            return 1
    print(f"load it: MINARI_DATASETS_PATH={out} python -c \"import minari; "
          f"print(minari.load_dataset('{summary['dataset']}'))\"")
    return 0
