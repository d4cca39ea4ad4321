"""Real-time scheduling of the node's step thread (opt-in: parameter ``step_rt_priority``).

On shared cores a large scene's step crosses the period in its tail, and a
normal thread or process that takes its core makes that worse. A thread under
``SCHED_FIFO`` runs before every normal (``SCHED_OTHER``) thread on its core, so
other work cannot preempt the step (docs/benchmarks/node.md); it still waits for
the GIL where the marker thread holds it (at most the switch interval the node
sets, :data:`SWITCH_INTERVAL`).

``SCHED_RESET_ON_FORK`` goes with it: threads and processes started later by
the step thread (a recorder, a planner pool) start under normal scheduling
instead of inheriting a real-time policy they were not written for. The
threads the node started before (markers, planner, DDS) keep theirs.

Raising a policy needs ``CAP_SYS_NICE`` or an rtprio limit (``ulimit -r``;
``/etc/security/limits.conf``: ``@realtime - rtprio 99``, as ros2_control's
real-time guide sets up). Without it the call is refused and the node says so
in one line and runs as before. Linux also keeps 5% of each second for normal
threads (``/proc/sys/kernel/sched_rt_runtime_us``), so a step that runs away
cannot lock a core.
"""
from __future__ import annotations

import os
import sys
import threading

SWITCH_INTERVAL = 0.0005
"""Seconds a thread may hold the GIL before another waiting thread gets it (Python's default: 0.005): what the
nodes set, so a worker thread that holds the GIL (tissue_sim_node's markers, tissue_controller's planning) hands
it to a waiting callback within 0.5 ms."""


def nice_this_thread(nice: int) -> int | None:
    """Add ``nice`` (>= 0) to the calling thread's niceness; its niceness then, None off Linux (where a niceness
    is the whole process's, left alone). A thread ID with PRIO_PROCESS names that one thread on Linux
    (setpriority(2), NOTES). Raises OSError where the system refuses (a sandbox)."""
    if not sys.platform.startswith("linux"):
        return None
    tid = threading.get_native_id()
    if nice > 0:
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    return os.getpriority(os.PRIO_PROCESS, tid)


def set_step_priority(priority: int) -> str | None:
    """Put the calling thread under SCHED_FIFO at ``priority`` (1-99); 0 leaves it.

    Returns None when done (or nothing asked), else one line saying why not.
    """
    if priority == 0:
        return None
    if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_FIFO"):
        return f"step_rt_priority={priority} not applied: this platform has no SCHED_FIFO; the step thread keeps its scheduling"
    policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))  # 0: the calling thread (Linux)
    except PermissionError:
        return (f"step_rt_priority={priority} not applied: this process may not raise its scheduling "
                f"(needs CAP_SYS_NICE or an rtprio limit >= {priority}, `ulimit -r` is "
                f"{_rtprio_limit()}); the step thread keeps normal scheduling")
    except OSError as exc:
        return f"step_rt_priority={priority} not applied: {exc}; the step thread keeps its scheduling"
    return None


def thread_scheduling() -> str:
    """The calling thread's policy and priority, e.g. ``SCHED_FIFO 50`` or ``SCHED_OTHER``."""
    if not hasattr(os, "sched_getscheduler"):
        return "unknown"
    policy = os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
    names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
             if hasattr(os, n)}
    name = names.get(policy, f"policy {policy}")
    if policy in (getattr(os, "SCHED_FIFO", None), getattr(os, "SCHED_RR", None)):
        return f"{name} {os.sched_getparam(0).sched_priority}"
    return name


def _rtprio_limit() -> str:
    try:
        import resource  # noqa: PLC0415  (POSIX only)
        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    except (ImportError, AttributeError, OSError):
        return "unknown"
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
