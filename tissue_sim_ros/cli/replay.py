"""``tissue-sim replay``: the command line of experiments/replay.py (the job) on ros/replay.py (the stepping)."""
from __future__ import annotations

import argparse

from ..experiments import replay as job
from ..ros.replay import MODES
from .config import add_config_arguments, config_from_args

HELP = "run the simulation offline on a bag's tool trajectory; write a bag, CSV, plots, frames"
DESCRIPTION = job.__doc__.split("\n\n", 1)[1] if job.__doc__ else HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", nargs="?", default=None, help="input bag: a rosbag2 directory, or a .mcap/.db3 file")
    parser.add_argument("--trajectory", default=None, metavar="PRESET|FILE",
                        help="replay a trajectory instead of a bag: a preset (experiment_a, experiment_b_shallow, "
                             "experiment_b_steep, authors) or a .csv (time,x,y,yaw) / .yaml trajectory file")
    parser.add_argument("--out", required=True, help="output directory (created; must not hold a replay already)")
    parser.add_argument("--tool-topic", default=None,
                        help="topic of the tool pose (PoseStamped, Pose, TransformStamped, TFMessage, "
                             "PoseWithCovarianceStamped, Odometry); default: the one pose topic in the bag "
                             "other than the node's own output tool/applied_pose")
    parser.add_argument("--frame", default=None, help="TF child frame of the tool (for tf2_msgs/TFMessage topics)")
    parser.add_argument("--twist-topic", default=None,
                        help="TwistStamped/Twist topic of the tool velocity (default: derived from poses)")
    add_config_arguments(parser)
    parser.add_argument("--mode", choices=MODES, default="per-message",
                        help="one step per tool message (default, = node lock-step), steps at 1/dt with "
                             "the pose interpolated, or applied: the node's own recording (tool/applied_*) "
                             "stepped exactly as the node did (bit for bit)")
    parser.add_argument("--time-source", choices=("header", "bag"), default="header",
                        help="sample times from header stamps (default) or bag receive times")
    parser.add_argument("--strict", action="store_true",
                        help="a tool sample that would be skipped (repeated or out-of-order time, non-finite "
                             "position, invalid quaternion) is an error (exit 2) instead of a counted skip")
    parser.add_argument("--frame-every", type=int, default=0,
                        help="write a PNG frame every K steps (default: about 40 frames in all; -1: none)")
    parser.add_argument("--video", action="store_true", help="also write replay.mp4 (needs the video extra)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage of the output bag")
    parser.add_argument("--points-every", type=int, default=1,
                        help="write tissue/points every K steps (default 1, as the node at its default points_rate)")
    parser.add_argument("--no-bag", action="store_true", help="do not write the output bag (fastest)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    return job.run_replay(job.ReplayJob(
        out=args.out, config=config_from_args(args), bag=args.bag, trajectory=args.trajectory,
        params_file=args.params, overrides=list(args.set or []), tool_topic=args.tool_topic, frame=args.frame,
        twist_topic=args.twist_topic, mode=args.mode, time_source=args.time_source, strict=args.strict,
        frame_every=args.frame_every, video=args.video, storage=args.storage, points_every=args.points_every,
        bag_output=not args.no_bag, progress=not args.no_progress))
