"""The step thread's real-time scheduling (tissue_sim_ros/ros/realtime.py, parameter step_rt_priority)."""
from __future__ import annotations

import os
import sys
import threading
from typing import Any

import pytest

from tissue_sim_ros.core.config import BY_NAME, coerce
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.ros.realtime import set_step_priority, thread_scheduling

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread scheduling policies: Linux")


def _in_thread(fn: Any) -> Any:
    """Run fn on a fresh thread (a policy set there dies with it) and return what it returned."""
    out: list[Any] = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join(10.0)
    assert not t.is_alive()
    return out[0]


def may_use_fifo(priority: int) -> bool:
    """Whether a thread of this process may take SCHED_FIFO at ``priority`` (tried on a throwaway thread)."""

    def probe() -> bool:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except PermissionError:
            return False
        return True
    return _in_thread(probe)


@linux
def test_zero_leaves_the_thread_as_it_was() -> None:
    assert _in_thread(lambda: (set_step_priority(0), thread_scheduling())) == (None, "SCHED_OTHER")


@linux
def test_a_granted_priority_is_the_callers_alone_and_not_inherited() -> None:
    if not may_use_fifo(7):
        pytest.skip("this process may not use SCHED_FIFO (no CAP_SYS_NICE, rtprio limit 0): the refusal is tested below")

    def in_step_thread() -> tuple[Any, str, str]:
        refused = set_step_priority(7)
        # a thread started by the step thread (a recorder, a pool's manager) starts normal
        child = _in_thread(thread_scheduling)
        return refused, thread_scheduling(), child

    refused, own, child = _in_thread(in_step_thread)
    assert refused is None
    assert own == "SCHED_FIFO 7"
    assert child == "SCHED_OTHER"  # SCHED_RESET_ON_FORK
    assert thread_scheduling() == "SCHED_OTHER"  # the caller's other threads keep theirs


@linux
def test_a_refused_priority_is_one_line_naming_the_value(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: Any) -> None:
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    why = set_step_priority(42)
    assert why is not None and "\n" not in why
    assert "step_rt_priority=42 not applied" in why and "CAP_SYS_NICE" in why and "ulimit -r" in why
    assert thread_scheduling() == "SCHED_OTHER"


@pytest.mark.parametrize("value", [-1, 100])
def test_out_of_range_priorities_are_refused_by_the_parameter_check(value: int) -> None:
    with pytest.raises(InputError, match=rf"parameter step_rt_priority={value}: expected 0 \(normal scheduling\)"):
        coerce(BY_NAME["step_rt_priority"], value)
    assert coerce(BY_NAME["step_rt_priority"], 99) == 99
