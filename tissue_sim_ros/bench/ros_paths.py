"""``tissue-sim bench ros``: the ROS layer's two hand-made fast paths against what the libraries offer.

* CDR: each output message of the node encoded (and decoded) as the node does (by hand from NumPy for the
  MarkerArray, :mod:`~tissue_sim_ros.ros.messages.markers`; through ``rosbags``' typestore for the rest,
  PointCloud2 from and to its structured array), through the typestore from a message object, and as rclpy
  message objects through ``serialize_message``: microseconds per message, the best of 3 repeats. The markers
  are a scene of ``--triangles`` triangles: its tissue triangle list, wireframe and tool.
* Publishing a 1 MB MarkerArray: rclpy's ``Publisher.publish(bytes)`` (holds the GIL inside rcl) against
  :class:`~tissue_sim_ros.ros.raw_publish.GilFreePublisher` (rcl's function through ctypes, which lets the GIL
  go). A subscriber in another process on a private ROS domain; in this one, a thread publishes ``--arrays``
  arrays at 30 Hz while a Python loop (what the node's step thread is) notes every gap between its turns
  longer than 1 ms; a gap that overlaps a publish call is one the publish held the loop up (the others are the
  machine's scheduling, alike for both), and a publish during which the loop did not turn once is ``frozen``
  (held, or descheduled, for all of it). The two publishers take turns, round by round (``--rounds``), so the
  machine's load falls on both alike; Python's switch interval is the node's (0.5 ms).

Prints both tables with the 1-minute load average before and after, writes ``ros_paths.csv``.
"""
from __future__ import annotations

import csv
import os
import statistics
import subprocess
import sys
import threading
import time
import timeit
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core.errors import output_dir
from ..core.mesh import mesh_rectangle

SUBSCRIBER = """
import rclpy, sys
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray
from tissue_sim_ros.ros import qos
rclpy.init(args=[])
node = Node("bench_ros_paths_subscriber")
node.create_subscription(MarkerArray, "bench_markers", lambda data: None, qos.state_stream(qos.MARKER_DEPTH), raw=True)
try:
    rclpy.spin(node)
except Exception:  # SIGTERM: the context shut down under the executor
    pass
"""


def _best_us(fn: Callable[[], Any], number: int) -> float:
    return min(timeit.repeat(fn, number=number, repeat=3)) / number * 1e6


def _scene(triangles: int) -> tuple[Any, np.ndarray]:
    """A SceneEncoder of a rectangle meshed to about ``triangles`` triangles, and its positions."""
    from ..core.physics.model import Model, SimParams  # noqa: PLC0415
    from ..ros.messages import SceneEncoder  # noqa: PLC0415

    spacing = 0.1 / np.sqrt(triangles / 2.3)
    model = Model.from_mesh(mesh_rectangle(0.1, 0.1, spacing), SimParams())
    enc = SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body,
                       tool_rounded_box=(0.02, 0.0025, 0.0))
    return enc, model.particle_q0.copy()


def _rclpy_marker_array(data: bytes) -> Any:
    from rclpy.serialization import deserialize_message  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    return deserialize_message(data, MarkerArray)


def cdr_rows(triangles: int = 5000) -> list[dict[str, Any]]:
    """Encode and decode times [us] of each output message, by hand, through the typestore and through rclpy."""
    from rclpy.serialization import deserialize_message, serialize_message  # noqa: PLC0415
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from ..ros import messages as m  # noqa: PLC0415
    from ..ros.typestore import typestore  # noqa: PLC0415

    ts = typestore()
    enc, q = _scene(triangles)
    strain = enc.vertex_strain(q)
    small = {
        "std_msgs/msg/Float64": m.encode_float64(1.5),
        "std_msgs/msg/Float64MultiArray": m.encode_float64_multiarray(np.zeros((1, 4)), ["body:a", "term:w,x,y,z"]),
        "geometry_msgs/msg/PoseStamped": m.encode_pose_stamped((1, 2), "world", 0.1, 0.2, 0.3),
        "geometry_msgs/msg/TwistStamped": m.encode_twist_stamped((1, 2), "world", 0.1, 0.2, 0.3),
        "geometry_msgs/msg/WrenchStamped": m.encode_wrench_stamped((1, 2), "world", (1.0, 2.0, 0.0), (0, 0, 0.5)),
        "sensor_msgs/msg/JointState": m.encode_joint_state((1, 2), "", ["jaw"], [0.5]),
    }
    encoders = {"std_msgs/msg/Float64": lambda: m.encode_float64(1.5),
                "std_msgs/msg/Float64MultiArray": lambda: m.encode_float64_multiarray(np.zeros((1, 4)),
                                                                                       ["body:a", "term:w,x,y,z"]),
                "geometry_msgs/msg/PoseStamped": lambda: m.encode_pose_stamped((1, 2), "world", 0.1, 0.2, 0.3),
                "geometry_msgs/msg/TwistStamped": lambda: m.encode_twist_stamped((1, 2), "world", 0.1, 0.2, 0.3),
                "geometry_msgs/msg/WrenchStamped": lambda: m.encode_wrench_stamped((1, 2), "world", (1.0, 2.0, 0.0),
                                                                                   (0, 0, 0.5)),
                "sensor_msgs/msg/JointState": lambda: m.encode_joint_state((1, 2), "", ["jaw"], [0.5])}
    rows = []
    for msgtype, data in small.items():
        pkg, _, name = msgtype.split("/")
        cls = getattr(__import__(f"{pkg}.msg", fromlist=[name]), name)
        obj = deserialize_message(data, cls)
        rows.append({"message": msgtype.split("/")[-1], "bytes": len(data), "hand_encode_us": "",
                     "typestore_encode_us": _best_us(encoders[msgtype], 5000),
                     "rclpy_encode_us": _best_us(lambda o=obj: serialize_message(o), 5000),
                     "hand_decode_us": "",
                     "typestore_decode_us": _best_us(lambda d=data, t=msgtype: ts.deserialize_cdr(d, t), 5000),
                     "rclpy_decode_us": _best_us(lambda d=data, c=cls: deserialize_message(d, c), 5000)})
    cloud = enc.point_cloud((1, 2), "world", q, strain)
    rows.append({"message": "PointCloud2", "bytes": len(cloud), "hand_encode_us": "",
                 "typestore_encode_us": _best_us(lambda: enc.point_cloud((1, 2), "world", q, strain), 200),
                 "rclpy_encode_us": _best_us(lambda o=deserialize_message(cloud, PointCloud2): serialize_message(o), 200),
                 "hand_decode_us": "", "typestore_decode_us": _best_us(lambda: m.decode_point_cloud(cloud), 200),
                 "rclpy_decode_us": _best_us(lambda: deserialize_message(cloud, PointCloud2), 200)})
    markers = enc.markers((1, 2), "world", q, strain, tool_pose=(0.05, 0.12, 0.0))
    name = "visualization_msgs/msg/MarkerArray"
    obj, ts_obj = deserialize_message(markers, MarkerArray), ts.deserialize_cdr(markers, name)
    rows.append({"message": "MarkerArray", "bytes": len(markers),
                 "hand_encode_us": _best_us(lambda: enc.markers((1, 2), "world", q, strain, tool_pose=(0.05, 0.12, 0.0)), 20),
                 "typestore_encode_us": _best_us(lambda: ts.serialize_cdr(ts_obj, name), 3),
                 "rclpy_encode_us": _best_us(lambda: serialize_message(obj), 3),
                 "hand_decode_us": _best_us(lambda: m.decode_marker_array(markers), 20),
                 "typestore_decode_us": _best_us(lambda: ts.deserialize_cdr(markers, name), 3),
                 "rclpy_decode_us": _best_us(lambda: deserialize_message(markers, MarkerArray), 3)})
    return rows


class _Ticker:
    """A Python loop on its own thread noting each gap (start, end) between its turns longer than ``threshold`` [s]."""

    def __init__(self, threshold: float = 1e-3) -> None:
        self.threshold = threshold
        self.gaps: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        last = time.perf_counter()
        while not self._stop.is_set():
            now = time.perf_counter()
            if now - last > self.threshold:
                self.gaps.append((last, now))
            last = now

    def __enter__(self) -> "_Ticker":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def _publish_round(publisher: Any, data: bytes, arrays: int, rate: float) -> dict[str, Any]:
    """``arrays`` publishes at ``rate``: each call's (start, end), and the loop's gaps that overlap one."""
    calls: list[tuple[float, float]] = []
    with _Ticker() as ticker:
        t_next = time.perf_counter()
        for _ in range(arrays):
            t0 = time.perf_counter()
            publisher.publish(data)
            calls.append((t0, time.perf_counter()))
            t_next += 1.0 / rate
            time.sleep(max(0.0, t_next - time.perf_counter()))
    held = [g for g in ticker.gaps if any(g[0] < c1 and c0 < g[1] for c0, c1 in calls)]
    # a publish the loop did not turn once during: the loop was held (or descheduled) for all of it
    frozen = sum(any(g0 <= c0 and c1 <= g1 for g0, g1 in ticker.gaps) for c0, c1 in calls)
    return {"calls": [c1 - c0 for c0, c1 in calls], "held": [g1 - g0 for g0, g1 in held], "gaps": len(ticker.gaps),
            "frozen": frozen}


def _wait_for_subscriber(pub: Any, proc: subprocess.Popen, timeout: float) -> None:
    end = time.monotonic() + timeout
    while pub.get_subscription_count() < 1:
        if proc.poll() is not None or time.monotonic() > end:
            raise RuntimeError("the subscriber process did not match the publisher")
        time.sleep(0.05)


def publish_rows(arrays: int = 150, rounds: int = 2, triangles: int = 5000, rate: float = 30.0) -> list[dict[str, Any]]:
    """rclpy's publish against the ctypes one: publish time and the Python loop's gaps > 1 ms, per publisher."""
    import rclpy  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.node import Node  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from ..ros import qos  # noqa: PLC0415
    from ..ros.domain import free_domain_id  # noqa: PLC0415
    from ..ros.raw_publish import GilFreePublisher  # noqa: PLC0415
    from ..ros.realtime import SWITCH_INTERVAL  # noqa: PLC0415

    enc, q = _scene(triangles)
    data = enc.markers((1, 2), "world", q, enc.vertex_strain(q), tool_pose=(0.05, 0.12, 0.0))
    domain = free_domain_id()
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.Popen([sys.executable, "-c", SUBSCRIBER], env=env, stdout=subprocess.DEVNULL)
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    switch = sys.getswitchinterval()
    results: dict[str, list[dict[str, Any]]] = {"rclpy": [], "ctypes": []}
    try:
        node = Node("bench_ros_paths", context=context)
        plain = node.create_publisher(MarkerArray, "bench_markers", qos.state_stream(qos.MARKER_DEPTH))
        publishers = {"rclpy": plain, "ctypes": GilFreePublisher(plain)}
        _wait_for_subscriber(plain, proc, 30.0)
        sys.setswitchinterval(SWITCH_INTERVAL)
        for _ in range(rounds):
            for name, pub in publishers.items():
                results[name].append(_publish_round(pub, data, arrays, rate))
    finally:
        sys.setswitchinterval(switch)
        rclpy.shutdown(context=context)
        proc.terminate()
        proc.wait(timeout=10)
    rows = []
    for name, runs in results.items():
        calls = [c for r in runs for c in r["calls"]]
        rows.append({"publisher": name, "bytes": len(data), "arrays": len(calls),
                     "publish_ms_median": 1e3 * statistics.median(calls), "publish_ms_max": 1e3 * max(calls),
                     "frozen_publishes": " / ".join(str(r["frozen"]) for r in runs),
                     "held_over_1ms": " / ".join(str(len(r["held"])) for r in runs),
                     "longest_held_ms": " / ".join(f"{1e3 * max(r['held'], default=0.0):.2f}" for r in runs),
                     "other_gaps": " / ".join(str(r["gaps"] - len(r["held"])) for r in runs)})
    return rows


def _table(rows: list[dict[str, Any]]) -> str:
    keys = list(rows[0])
    text = [[f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]) for k in keys] for r in rows]
    widths = [max(len(k), *(len(t[i]) for t in text)) for i, k in enumerate(keys)]
    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, widths))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(t, widths)) for t in text]
    return "\n".join(lines)


def run(out: str | Path, *, triangles: int = 5000, arrays: int = 150, rounds: int = 2, publish: bool = True) -> int:
    """Both measurements (``publish=False``: CDR only); the tables printed, ``ros_paths.csv`` written."""
    out_dir = output_dir(out, "--out")
    out_dir.mkdir(parents=True, exist_ok=True)
    load = [os.getloadavg()[0]]
    cdr = cdr_rows(triangles)
    print(f"CDR, microseconds per message (best of 3), {triangles} triangles:\n{_table(cdr)}\n")
    pub = publish_rows(arrays, rounds, triangles) if publish else []
    if pub:
        print(f"publishing a MarkerArray at 30 Hz, {rounds} rounds each; a Python loop beside it held up > 1 ms by "
              f"a publish (per round), its longest such hold, and its other gaps > 1 ms:\n"
              f"{_table(pub)}\n")
    load.append(os.getloadavg()[0])
    print(f"load average (1 min): {load[0]:.2f} at the start, {load[1]:.2f} at the end; {os.cpu_count()} cores")
    with (out_dir / "ros_paths.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        for rows in (cdr, pub):
            if rows:
                writer.writerow(list(rows[0]))
                writer.writerows([list(r.values()) for r in rows])
    return 0
