"""Test-wide fixtures: the ROS graph helpers of ``ros_env`` (isolated domain, processes, a client), and a
private temporary directory for every Ray cluster the tests start.

Ray writes a session directory (logs, sockets, spilled objects) under ``$RAY_TMPDIR/ray`` and never removes
it; by default that is ``/tmp/ray``, where every run of the suite left one more ``session_*`` behind. The
suite points ``RAY_TMPDIR`` at a directory of its own (set before anything imports Ray, inherited by the
commands the tests start) and removes it when the session ends.
"""
from __future__ import annotations

import os
import shutil
import tempfile

pytest_plugins = ("ros_env",)

#: The suite's Ray temporary directory (short: Ray's Unix sockets live under it, and their paths are limited).
RAY_TMPDIR = tempfile.mkdtemp(prefix="tsr_ray_")
os.environ["RAY_TMPDIR"] = RAY_TMPDIR


def pytest_sessionfinish(session, exitstatus) -> None:
    shutil.rmtree(RAY_TMPDIR, ignore_errors=True)
