"""The test harness itself: a node started by a test ends when the test process dies."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest


@pytest.mark.skipif(sys.platform != "linux", reason="PR_SET_PDEATHSIG is Linux's")
def test_child_ends_when_the_test_process_is_killed(tmp_path):
    # a stand-in for pytest: starts a long child through RosProcess, prints its pid, then dies by SIGKILL
    here = os.path.dirname(os.path.abspath(__file__))
    script = (
        "import os, signal, sys\n"
        f"sys.path.insert(0, {here!r})\n"
        "from ros_env import RosProcess\n"
        f"p = RosProcess([sys.executable, '-c', 'import time; time.sleep(60)'], dict(os.environ), "
        f"__import__('pathlib').Path({str(tmp_path / 'child.log')!r}))\n"
        "print(p.proc.pid, flush=True)\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    pid = int(out.stdout.split()[0])
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return  # gone (reaped by init once it ended)
        with open(f"/proc/{pid}/stat") as f:
            if f.read().split(")")[-1].split()[0] == "Z":
                return  # ended, waiting to be reaped
        time.sleep(0.05)
    os.kill(pid, 9)
    pytest.fail(f"child {pid} still running 10 s after its parent was killed")


def test_free_domain_id_skips_a_domain_in_use():
    # a stand-in participant 0 of domain d: its unicast discovery port 7410 + 250 d bound
    import socket  # noqa: PLC0415

    from tissue_sim_ros.ros.domain import domain_in_use, free_domain_id

    d = free_domain_id()
    assert 1 <= d <= 100 and not domain_in_use(d)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("0.0.0.0", 7410 + 250 * d))
        assert domain_in_use(d)
        assert free_domain_id() != d
    assert not domain_in_use(d)
