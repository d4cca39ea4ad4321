"""Shared helpers for tests that start ROS 2 processes: an isolated graph, processes, a client.

Isolation: every test session picks its own ``ROS_DOMAIN_ID`` (from its pid) and
sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, both in this process (for the
test client) and in every child, so parallel runs never hear each other and
nothing leaves 127.0.0.1. Fast DDS's default discovery takes 2-3 s; tests may
use the faster announcement profile in ``/work/shared/fastdds_fast_discovery.xml``
(the product never depends on it).

Use from a test module::

    from ros_env import RosClient  # the fixtures ros_env, ros_client, start_process come from conftest.py

    def test_x(ros_client, start_process):
        node = start_process(["tissue_sim_node", "--ros-args", "-p", "dt:=0.01"], name="sim")
        sub = ros_client.raw_subscription(PointCloud2, "tissue/points", qos)
        ros_client.wait_for_publisher("tissue/points", timeout=15, process=node)
        msgs = ros_client.spin_until(lambda: len(sub.messages) >= 3, timeout=10, process=node)

Every process started through ``start_process`` is ended by the fixture's
finalizer (SIGTERM, then SIGKILL after a timeout); ``RosProcess.stop`` returns
the exit code so a test can assert a clean shutdown.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from tissue_sim_ros.bench.node import end_with_parent  # SIGTERM to a child when the test process dies

FAST_DISCOVERY_XML = Path("/work/shared/fastdds_fast_discovery.xml")
VENV_BIN = Path(sys.executable).parent


def pick_domain_id() -> int:
    """A ROS_DOMAIN_ID in [1, 100] that no other participant on this machine uses (a benchmark or another
    suite beside this one), starting from the process id (valid on Linux, away from the default 0)."""
    from tissue_sim_ros.ros.domain import free_domain_id  # noqa: PLC0415

    return free_domain_id()


def isolated_env(domain_id: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """A child environment: the parent's (the ROS wheels set LD_LIBRARY_PATH there) plus isolation settings."""
    env = dict(os.environ if base is None else base)
    env.update({
        "ROS_DOMAIN_ID": str(domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "PYTHONUNBUFFERED": "1",
        "RCUTILS_COLORIZED_OUTPUT": "0",
        "RCUTILS_LOGGING_BUFFERED_STREAM": "0",
    })
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; the range above replaces it
    env.pop("ROS_STATIC_PEERS", None)
    if FAST_DISCOVERY_XML.is_file():
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FAST_DISCOVERY_XML)
    return env


def console_script(name: str) -> str:
    """Path of a console script of this venv (``tissue_sim_node``), else from PATH."""
    candidate = VENV_BIN / name
    if candidate.exists():
        return str(candidate)
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"console script {name!r} not found in {VENV_BIN} or PATH")
    return found


class RosProcess:
    """A child process with its output in a log file; ``stop()`` ends it and returns the exit code."""

    def __init__(self, cmd: list[str], env: dict[str, str], log_path: Path, cwd: str | None = None) -> None:
        self.cmd = cmd
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115  closed in stop()
        self.proc = subprocess.Popen(cmd, env=env, stdout=self._log, stderr=subprocess.STDOUT, cwd=cwd,
                                     preexec_fn=end_with_parent)

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        """Everything the process printed so far (stdout and stderr)."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def wait(self, timeout: float) -> int:
        """Wait for the process to exit by itself; its exit code (TimeoutExpired if it does not)."""
        code = self.proc.wait(timeout=timeout)
        self._log.close()
        return code

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        """Send ``sig``, wait up to ``timeout`` s, then SIGKILL; the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        if not self._log.closed:
            self._log.close()
        return self.proc.returncode


@dataclass
class RawSubscription:
    """Messages received as serialized bytes, with their arrival time (time.monotonic and time.time)."""

    topic: str
    messages: list[bytes] = field(default_factory=list)
    arrivals: list[float] = field(default_factory=list)
    """Wall-clock (time.time) arrival of each message [s]."""
    sub: Any = None

    def callback(self, data: bytes) -> None:
        self.arrivals.append(time.time())
        self.messages.append(data)

    def clear(self) -> None:
        self.messages.clear()
        self.arrivals.clear()


class RosClient:
    """The test's own ROS participant: an rclpy Context, one node and an executor, on the isolated domain."""

    def __init__(self, domain_id: int, name: str = "test_client") -> None:
        import rclpy  # noqa: PLC0415  (only tests that use ROS import it)
        from rclpy.context import Context  # noqa: PLC0415
        from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def raw_subscription(self, msg_type: Any, topic: str, qos: Any) -> RawSubscription:
        """Subscribe with ``raw=True``: messages arrive as CDR bytes (decode with numpy)."""
        holder = RawSubscription(topic)
        holder.sub = self.node.create_subscription(msg_type, topic, holder.callback, qos, raw=True)
        return holder

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.01, max(end - time.monotonic(), 0.0)))

    def spin_until(self, predicate: Callable[[], Any], timeout: float, process: RosProcess | None = None,
                   what: str = "condition") -> Any:
        """Spin until ``predicate()`` is truthy and return it; fail the test after ``timeout`` s.

        If ``process`` dies meanwhile, fail at once with its output.
        """
        end = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if process is not None and not process.alive():
                pytest.fail(f"{process.cmd[0]} exited with {process.returncode} while waiting for {what}:\n"
                            f"{process.output()[-3000:]}")
            if time.monotonic() > end:
                tail = f"\n--- {process.cmd[0]} output ---\n{process.output()[-3000:]}" if process is not None else ""
                pytest.fail(f"timed out after {timeout} s waiting for {what}{tail}")
            self.executor.spin_once(timeout_sec=0.01)

    def wait_for_publisher(self, topic: str, timeout: float, process: RosProcess | None = None) -> None:
        """Wait until some participant publishes ``topic`` (resolved against the client node)."""
        name = self.node.resolve_topic_name(topic)
        self.spin_until(lambda: self.node.count_publishers(name) > 0, timeout, process, f"a publisher on {name}")

    def wait_for_subscriber(self, publisher: Any, timeout: float, process: RosProcess | None = None) -> None:
        """Wait until ``publisher`` has a matched subscription."""
        self.spin_until(lambda: publisher.get_subscription_count() > 0, timeout, process,
                        f"a subscriber on {publisher.topic_name}")

    def call(self, client: Any, request: Any, timeout: float, process: RosProcess | None = None) -> Any:
        """Call a service (waiting for it first); the response."""
        self.spin_until(lambda: client.service_is_ready(), timeout, process, f"service {client.srv_name}")
        future = client.call_async(request)
        self.spin_until(future.done, timeout, process, f"a response from {client.srv_name}")
        return future.result()

    def close(self) -> None:
        import rclpy  # noqa: PLC0415

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def ros_env() -> Iterator[dict[str, str]]:
    """The isolated environment for children; also applied to this process (for the client) during the session."""
    env = isolated_env(pick_domain_id())
    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE",
            "ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS")
    saved = {k: os.environ.get(k) for k in keys}
    for k in keys:
        if k in env:
            os.environ[k] = env[k]
        else:
            os.environ.pop(k, None)
    yield env
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope="module")
def ros_client(ros_env: dict[str, str]) -> Iterator[RosClient]:
    """A RosClient on the session's domain, closed after the module."""
    client = RosClient(int(ros_env["ROS_DOMAIN_ID"]))
    yield client
    client.close()


@pytest.fixture
def start_process(ros_env: dict[str, str], tmp_path: Path) -> Iterator[Callable[..., RosProcess]]:
    """Factory: ``start_process(cmd, name="x", env_changes={...})`` -> RosProcess; all are stopped at teardown.

    A bare console-script name as ``cmd[0]`` is resolved in this venv.
    """
    started: list[RosProcess] = []

    def start(cmd: list[str], name: str = "proc", env_changes: dict[str, str] | None = None,
              cwd: str | None = None) -> RosProcess:
        cmd = list(cmd)
        if os.sep not in cmd[0]:
            cmd[0] = console_script(cmd[0])
        env = dict(ros_env)
        env.update(env_changes or {})
        proc = RosProcess(cmd, env, tmp_path / f"{name}-{len(started)}.log", cwd=cwd)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        proc.stop(signal.SIGTERM, timeout=10)
