"""The node's TISSUE_SIM_TRACEMALLOC debugging aid: off unless asked, a bad value named, growth listed."""
from __future__ import annotations

import tracemalloc

import pytest

pytest.importorskip("rclpy")

from tissue_sim_ros.ros.node import MemoryTrace  # noqa: E402


class Log:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def info(self, message: str) -> None:
        self.lines.append(message)

    warning = info


def test_off_unless_set_and_a_bad_period_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    log = Log()
    monkeypatch.delenv(MemoryTrace.ENV, raising=False)
    assert MemoryTrace.from_env(log) is None and not log.lines
    monkeypatch.setenv(MemoryTrace.ENV, "-5")
    assert MemoryTrace.from_env(log) is None
    assert "TISSUE_SIM_TRACEMALLOC='-5'" in log.lines[0] and "period > 0" in log.lines[0]


def test_lists_what_grew_since_the_baseline(monkeypatch: pytest.MonkeyPatch) -> None:
    log = Log()
    monkeypatch.setenv(MemoryTrace.ENV, "1")
    trace = MemoryTrace.from_env(log)
    try:
        trace.maybe_report(trace._next - 0.5)  # before the period: nothing
        assert not log.lines
        trace.maybe_report(trace._next)
        assert log.lines[-1].startswith("tracemalloc baseline")
        kept = [bytearray(256) for _ in range(2000)]  # ~0.5 MiB made after the baseline, still alive
        trace.maybe_report(trace._next)
        report = log.lines[-1].splitlines()
        assert report[0].startswith("tracemalloc:") and "test_memory_trace.py" in report[1]
        blocks = int(report[1].split("(+")[1].split(" blocks")[0])
        assert blocks >= 2000, report[:3]  # a bytearray and its buffer
        assert len(kept) == 2000
    finally:
        tracemalloc.stop()
