"""Pieces of `tissue-sim bench node` that need no ROS graph (the command itself: test_ros_node)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from tissue_sim_ros.bench.node_memory import memory_parts_kib as _memory_parts_kib
from tissue_sim_ros.bench.node_memory import rss_kib as _rss_kib

SMAPS = """\
55d0c0000000-55d0c0021000 r--p 00000000 08:01 1234  /usr/bin/python3.11
Size:                132 kB
Rss:                 128 kB
55d0c1000000-55d0c5000000 rw-p 00000000 00:00 0     [heap]
Size:              65536 kB
KernelPageSize:        4 kB
Rss:               41000 kB
Pss:               41000 kB
7f0000000000-7f0004000000 rw-p 00000000 00:00 0
Size:              65536 kB
Rss:               12000 kB
7ffd00000000-7ffd00021000 rw-p 00000000 00:00 0     [stack]
Rss:                  64 kB
"""

STATUS = "Name:\tpython3\nVmRSS:\t  245000 kB\nRssAnon:\t  107000 kB\nRssFile:\t  137000 kB\nRssShmem:\t    1000 kB\n"


def test_memory_parts_read_the_heap_mapping_alone(tmp_path: Path) -> None:
    """RssAnon and RssFile from status; the [heap] mapping's Rss, not the arena beside it nor the stack."""
    (tmp_path / "42").mkdir()
    (tmp_path / "42" / "status").write_text(STATUS)
    (tmp_path / "42" / "smaps").write_text(SMAPS)
    assert _memory_parts_kib(42, tmp_path) == {"rss_anon_kib": 107000, "rss_file_kib": 137000, "heap_kib": 41000}


def test_an_unreadable_process_gives_minus_one_not_an_error(tmp_path: Path) -> None:
    assert _memory_parts_kib(42, tmp_path) == {"rss_anon_kib": -1, "rss_file_kib": -1, "heap_kib": -1}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")
def test_memory_parts_of_this_process_add_up_to_its_resident_set() -> None:
    pid = os.getpid()
    parts = _memory_parts_kib(pid)
    assert min(parts.values()) > 0, parts
    # VmRSS = RssAnon + RssFile + RssShmem (read a moment apart: a little slack); the [heap] is anonymous
    assert parts["rss_anon_kib"] + parts["rss_file_kib"] <= _rss_kib(pid) + 1024
    assert parts["heap_kib"] <= parts["rss_anon_kib"]



def _running(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie (state Z, waiting to be reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG")
@pytest.mark.parametrize("preexec", ["end_with_parent", "None"])
def test_a_benchmarks_child_ends_when_the_benchmark_is_killed(preexec: str) -> None:
    """A soak stopped by a signal left its node stepping: its children now get SIGTERM when the benchmark dies
    (and without end_with_parent the same child outlives it: the test can tell)."""
    import subprocess  # noqa: PLC0415
    import time  # noqa: PLC0415

    parent = subprocess.Popen(
        [sys.executable, "-c", "import subprocess, time\n"
         "from tissue_sim_ros.bench.node import end_with_parent\n"
         f"child = subprocess.Popen(['sleep', '30'], preexec_fn={preexec})\n"
         "print(child.pid, flush=True)\n"
         "time.sleep(30)\n"], stdout=subprocess.PIPE, text=True)
    child = -1
    try:
        child = int(parent.stdout.readline())
        assert _running(child)
        parent.kill()  # SIGKILL: no finally and no handler runs in the benchmark
        parent.wait(timeout=10)
        deadline = time.monotonic() + (5.0 if preexec != "None" else 1.0)  # the survivor: watched 1 s
        while _running(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _running(child) == (preexec == "None")
    finally:
        if parent.poll() is None:
            parent.kill()
        parent.stdout.close()
        if _running(child):
            os.kill(child, 9)


def test_the_node_benchmark_says_how_many_measurements_and_how_long_before_it_starts(capsys) -> None:
    """``bench node --seconds 3`` took minutes where its help said "measured time per scene": a default run
    measures every phase with the lock off and on, per scene and mode. The plan counts what the run does."""
    from tissue_sim_ros.bench.node import MODES, SCENES, MeasurementPlan
    from tissue_sim_ros.cli import main

    plan = MeasurementPlan(list(SCENES), list(MODES), phases=8, locks=(False, True), seconds=3.0, settle=2.0,
                           warmup=2.0)
    assert plan.windows == len(SCENES) * (8 * 2 + 1)
    assert plan.estimate > plan.windows * 3.0 + 8 * 2 * 2.0 * len(SCENES)
    assert plan.text.startswith(f"bench node: {plan.windows} measurements of 3 s") and "about" in plan.text
    plan.announce("paper timer, phase 1 of 8, phase_lock off")
    out = capsys.readouterr().out
    assert f"measurement 1 of {plan.windows}: paper timer" in out and "left" in out
    with pytest.raises(SystemExit):
        main(["bench", "node", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "length of one measurement" in help_text and "per scene [s]" not in help_text
