"""A ROS_DOMAIN_ID no other participant on this machine uses, for the private graphs of tests, benchmarks and the demo.

A process-id-based domain (``1 + pid % 100``) collides when two runs share a
machine: a test's recorder then records a benchmark's node on the same domain.
A domain is in use when its first
participant's unicast discovery port is bound: the DDS port mapping of the
RTPS standard (section 9.6.1.1, the defaults PB 7400, DG 250, d1 10) puts
participant 0 of domain d on UDP port 7410 + 250 d, and every DDS vendor in
ROS 2 follows it. No rclpy needed.
"""
from __future__ import annotations

import os
import socket

#: Linux supports domain ids up to 232 with the default port mapping; the private graphs use [1, 100] and
#: the demo [120, 219], as before, only skipping the ones in use.
PORT_BASE, DOMAIN_GAIN, UNICAST_OFFSET = 7400, 250, 10


def domain_in_use(domain_id: int) -> bool:
    """True when participant 0's unicast discovery port of ``domain_id`` is bound on this machine."""
    port = PORT_BASE + DOMAIN_GAIN * domain_id + UNICAST_OFFSET
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False


def free_domain_id(first: int = 1, count: int = 100) -> int:
    """A domain id in [first, first + count) not in use, starting from one picked by the process id.

    Falls back to the process id's pick when every one is in use (then the caller's graph may see others).
    """
    start = os.getpid() % count
    for k in range(count):
        d = first + (start + k) % count
        if not domain_in_use(d):
            return d
    return first + start
