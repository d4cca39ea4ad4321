"""Command-line options that several commands share, other than ``--params``/``--set`` (cli/config.py).

``--jobs``, ``--backend`` and ``--address`` say where a sweep runs (tissue-sim plan, tune, fit, bench
stability, bench fit). They are declared here, once, so every sweep spells and explains them alike;
the values are checked by the library that runs the sweep (core.sim.backends.check_jobs and
check_backend), so a Python caller gets the same one-line errors as the command line.
"""
from __future__ import annotations

import argparse
import math
from typing import Any

from ..core.errors import InputError
from ..core.sim.backends import BACKENDS


def positive_floats(text: str, option: str, *, numbers: str = "numbers", positive: str = "numbers > 0") -> list[float]:
    """A comma-separated list of numbers > 0 (``--spacings 0.1,0.05``); InputError naming ``option`` and the text.

    ``numbers`` and ``positive`` word the two refusals (``"comma-separated numbers in metres"``...).
    """
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{option}={text!r}: expected comma-separated {numbers}") from None
    if not values or any(not (math.isfinite(v) and v > 0) for v in values):
        raise InputError(f"{option}={text!r}: expected {positive}")
    return values


def add_backend_arguments(parser: argparse.ArgumentParser, *, jobs_default: int, jobs_help: str) -> None:
    """``--jobs``, ``--backend`` and ``--address``, with the command's own default and meaning of ``--jobs``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    jobs_default : int
        Workers when ``--jobs`` is not given.
    jobs_help : str
        What ``--jobs`` counts for this command; the Ray meaning is appended.
    """
    parser.add_argument("--jobs", type=int, default=jobs_default,
                        help=f"{jobs_help}; with --backend ray: Ray workers at a time")
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local: this machine's cores; ray: a Ray cluster (pip install '.[ray]'); the same "
                             "results")
    parser.add_argument("--address", default=None,
                        help="--backend ray: the cluster (HOST:6379, ray://HOST:10001; default RAY_ADDRESS or a "
                             "private single-node cluster on 127.0.0.1)")


def backend_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments ``jobs``, ``backend`` and ``address`` of :func:`add_backend_arguments`'s options.

    Unchecked: the library entry checks them where the command always has (its errors come in the same order).
    """
    return {"jobs": args.jobs, "backend": args.backend, "address": args.address}
