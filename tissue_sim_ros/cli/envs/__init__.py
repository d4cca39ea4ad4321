"""``tissue-sim envs COMMAND``: the command lines of the learning environments (tissue_sim_ros.envs).

``collect`` records a task's expert episodes as a Minari dataset; ``evaluate`` measures the expert and random
policies' success over seeded episodes. One module each (cli/__init__.py's COMMANDS names them), so
``--help`` of one imports neither gymnasium nor minari for the other; :func:`writable_dir` is their shared check
of ``--out``.
"""
from __future__ import annotations

import os
from pathlib import Path

from ...core.errors import InputError, output_dir


def writable_dir(path: str, option: str = "--out") -> Path:
    """``path`` as a directory this process can write, created now (before any work): InputError otherwise."""
    p = output_dir(path, option)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option} {str(p)!r}: cannot create it ({exc.strerror or exc}): expected a writable "
                         "directory") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(f"{option} {str(p)!r}: not writable: expected a directory you can write")
    return p
