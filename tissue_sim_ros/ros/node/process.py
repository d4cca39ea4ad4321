"""The node's process: the console script ``tissue_sim_node`` (:func:`main`) and what it sets for the whole
process: its own SIGINT/SIGTERM handling (:mod:`.shutdown`), the collector frozen after start-up, a short GIL
switch interval, glibc's heap kept small (:class:`HeapTrimmer`) and, for debugging a memory creep,
:class:`MemoryTrace`."""
from __future__ import annotations

import gc
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.signals import SignalHandlerOptions

from ...core.config import load_params_file
from ...core.errors import InputError
from ..realtime import SWITCH_INTERVAL, set_step_priority
from ..usage import msg_docs_dir, usage_head, wants_help
from .shutdown import SignalShutdown


def usage() -> str:
    """What ``tissue_sim_node --help`` prints."""
    about = (
        "A 2D soft tissue under a surgical tool, simulated as a ROS 2 node: it takes the tool's pose on tool/pose\n"
        "(and its velocity on tool/twist), steps the simulation at 1/dt of its clock (or once per pose with\n"
        "-p lock_step:=true) and publishes the deformed mesh (tissue/markers, tissue/points), the energy\n"
        "(tissue/energy/...), the reaction on the tool (tool/wrench), the tool each step used (tool/applied_*)\n"
        "and /diagnostics; services ~/reset, ~/pause, ~/plan_insertion. Ends on SIGINT/SIGTERM (exit 0);\n"
        "a bad parameter exits 2 naming it.\n\n")
    return (
        usage_head("tissue_sim_node", about, "-p lock_step:=true -p record_path:=run1")
        + "  e.g. tissue_sim_node --ros-args --params-file config/tissue_sim.yaml -p marker_rate:=10.0\n\n"
        f"Every topic, parameter (with its default and unit) and service: {msg_docs_dir()}\n"
        "(README.md, topics.md, parameters.md, services.md); `tissue-sim config` prints the resolved parameters.\n")


def params_files(argv: list[str]) -> list[str]:
    """The ``--params-file`` paths inside the ``--ros-args`` sections of a command line."""
    files, in_ros, it = [], False, iter(argv)
    for arg in it:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        elif in_ros and arg == "--params-file":
            files.append(next(it, ""))
    return files


def _glibc_function(name: str):
    """glibc's function ``name`` through ctypes, or None where there is no glibc (or no such function)."""
    import ctypes  # noqa: PLC0415
    import ctypes.util  # noqa: PLC0415

    lib = ctypes.util.find_library("c")
    if sys.platform != "linux" or lib is None:
        return None
    try:
        return getattr(ctypes.CDLL(lib), name)
    except (OSError, AttributeError):
        return None


def fix_mmap_threshold() -> None:
    """glibc: serve every allocation above 128 KiB by mmap, returned to the system when freed.

    A MarkerArray is ~1 MB of bytes made and dropped 30 times a second on the
    marker thread. glibc raises its mmap threshold after such frees, so later
    ones come from the heap and its arenas, which then keep growing. A fixed
    threshold keeps them out of the heap. No-op where there is no glibc.
    """
    mallopt = _glibc_function("mallopt")
    if mallopt is not None:
        mallopt(_M_MMAP_THRESHOLD, 128 * 1024)


_M_MMAP_THRESHOLD = -3
"""glibc's mallopt() parameter number (malloc.h)."""


class HeapTrimmer:
    """Give the heap's free pages back to the system every ``period`` seconds (glibc ``malloc_trim(0)``).

    Small allocations made and freed on two threads (step and markers) leave free
    pages inside glibc's arenas that it keeps; over an hour they show as resident
    memory that only grows under load. ``malloc_trim`` returns them (its time is
    reported on /diagnostics, ``heap_trim_ms_max``). Called from the diagnostics
    timer, never from the step. No-op where there is no glibc.
    """

    def __init__(self, period: float = 10.0) -> None:
        self.period = period
        self.trims = 0
        self.seconds_max = 0.0
        self._next = time.monotonic() + period
        self._trim = _glibc_function("malloc_trim")

    def maybe_trim(self, now: float) -> None:
        if self._trim is None or now < self._next:
            return
        self._next = now + self.period
        t0 = time.perf_counter()
        self._trim(0)
        self.seconds_max = max(self.seconds_max, time.perf_counter() - t0)
        self.trims += 1


class MemoryTrace:
    """Debugging a memory creep: Python allocations that grew since a baseline, logged every ``period`` s.

    On when the environment variable ``TISSUE_SIM_TRACEMALLOC`` gives the period
    [s] (e.g. ``TISSUE_SIM_TRACEMALLOC=60 tissue-sim bench node --soak 600``: the
    bench's node inherits it and logs to its log file). The baseline is taken one
    period after start (after warm-up); each report lists the ``top`` source lines
    whose live allocations grew most since, with the traced total. tracemalloc
    slows every allocation: not for timing runs.
    """

    ENV = "TISSUE_SIM_TRACEMALLOC"

    def __init__(self, logger: Any, period: float, top: int = 10) -> None:
        import tracemalloc  # noqa: PLC0415

        self._tm = tracemalloc
        self.logger, self.period, self.top = logger, period, top
        tracemalloc.start(12)
        self._baseline = None
        self._next = time.monotonic() + period

    @classmethod
    def from_env(cls, logger: Any) -> "MemoryTrace | None":
        value = os.environ.get(cls.ENV, "")
        if not value:
            return None
        try:
            period = float(value)
        except ValueError:
            period = math.nan
        if not (math.isfinite(period) and period > 0):
            logger.warning(f"{cls.ENV}={value!r}: expected a period > 0 s; not tracing")
            return None
        return cls(logger, period)

    def maybe_report(self, now: float) -> None:
        if now < self._next:
            return
        self._next = now + self.period
        snapshot = self._tm.take_snapshot().filter_traces((self._tm.Filter(False, self._tm.__file__),))
        if self._baseline is None:
            self._baseline = snapshot
            self.logger.info(f"tracemalloc baseline: {self._tm.get_traced_memory()[0] / 2**20:.2f} MiB traced")
            return
        stats = snapshot.compare_to(self._baseline, "traceback")
        lines = [f"tracemalloc: {self._tm.get_traced_memory()[0] / 2**20:.2f} MiB traced; grown since the baseline:"]
        for stat in stats[:self.top]:
            # innermost frame first (a Traceback runs from the oldest frame to the most recent)
            frames = " <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in reversed(stat.traceback[-6:]))
            lines.append(f"  {stat.size_diff / 1024:+.1f} KiB ({stat.count_diff:+d} blocks) {frames}")
        self.logger.info("\n".join(lines))


def main(args: list[str] | None = None) -> int:
    """Console script ``tissue_sim_node``: exit 0 on SIGINT/SIGTERM, 2 on a bad parameter (named).

    ``-h``/``--help`` outside ``--ros-args`` prints :func:`usage` and returns 0 before rclpy is initialised.
    """
    if wants_help(args):
        print(usage(), end="")
        return 0
    from . import TissueSimNode  # noqa: PLC0415  (the package imports this module)

    try:
        # read every --params-file ourselves first: a malformed one is one line naming it and where,
        # before rcl logs its own parse error
        for path in params_files(sys.argv if args is None else args):
            load_params_file(path)
    except InputError as exc:
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        return 2
    # signals are handled here, not by rclpy, so that one never ends the node inside a step's outputs (shutdown.py);
    # Python lets only the main thread install handlers
    own_signals = threading.current_thread() is threading.main_thread()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO if own_signals else None)
    except Exception as exc:  # noqa: BLE001  rcl's parse errors (a missing or malformed --params-file)
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        return 2
    signals = SignalShutdown(rclpy.get_default_context()) if own_signals else None
    node = None
    code = 0
    try:
        node = TissueSimNode()
        if signals is not None:
            signals.gate = node.output_gate
        # everything built so far lives as long as the node: keep the collector from rescanning it each step
        gc.collect()
        gc.freeze()
        # the marker worker holds the GIL while it encodes; a short switch interval hands it back to a
        # waking step within 0.5 ms instead of Python's default 5 ms
        sys.setswitchinterval(SWITCH_INTERVAL)
        fix_mmap_threshold()
        # this thread spins the executor: steps, poses and services run on it
        refused = set_step_priority(node.config.node.step_rt_priority)
        if refused is not None:
            node.get_logger().warning(refused)
        rclpy.spin(node)
    except InputError as exc:
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy_impl.RCLError:
        # SIGTERM/SIGINT shut the context down while a callback was publishing (diagnostics, the rest mesh; never
        # a step's outputs): a clean shutdown
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        try:
            rclpy.try_shutdown()
        except _rclpy_impl.RCLError:
            pass  # the signal handler shut the context down meanwhile ("rcl_shutdown already called")
        if signals is not None:
            signals.uninstall()
    return code
