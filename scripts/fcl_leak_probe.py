#!/usr/bin/env python3
"""How much heap each python-fcl distance query leaves behind (glibc's bytes in use, ``mallinfo2``).

heaptrack on a 17-minute 5k soak found one allocation site that grew without bound: a 24-byte
``std::__shared_count<fcl::CollisionGeometry*>`` made by ``fcl.CollisionObject(...)``. python-fcl's
``CollisionObject.__dealloc__`` frees its C++ object with ``free`` instead of ``delete`` (upstream
``src/fcl/fcl.pyx``, BerkeleyAutomation/python-fcl), so the object's ``shared_ptr`` member never releases its
control block. The contact (``core/contact/collision.py``, ``Contact.body_distance``) builds one BVH and one
CollisionObject per body within reach of the tool per step (the BVH changes with the tissue every step, and
python-fcl 0.7 cannot rebuild a BVH in place: ``beginModel`` on a built model clears it, warns on stderr and
returns an error). This measures the bytes per query three ways, side by side in one process:

* ``contact``: ``Simulation.step`` with the paper scene's box tool hovering within reach of the lower tissue
  (the product's path; queries counted by wrapping ``fcl.distance``);
* ``CollisionObject``: a BVH and a CollisionObject made and dropped (what each query does);
* ``BVHModel only``: the BVH alone, no CollisionObject (the control).

Usage: python scripts/fcl_leak_probe.py [--queries N]
"""
from __future__ import annotations

import argparse
import ctypes

import fcl
import numpy as np


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                     "fsmblks", "uordblks", "fordblks", "keepcost")]


_libc = ctypes.CDLL("libc.so.6")
_libc.mallinfo2.restype = _MallInfo2


def heap_in_use() -> int:
    """Bytes glibc's malloc has handed out and not had back (all arenas)."""
    return int(_libc.mallinfo2().uordblks)


def _mesh(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    v = np.zeros((n + 2, 3))
    v[:, 0] = np.linspace(0.0, 1.0, n + 2)
    v[:, 1] = 0.3 + 0.01 * rng.standard_normal(n + 2)
    v[1::2, 1] -= 0.05
    return v, np.array([[i, i + 1, i + 2] for i in range(n)], dtype=np.int32)


def probe_bare(queries: int, with_object: bool) -> tuple[int, int]:
    rng = np.random.default_rng(0)
    meshes = [_mesh(rng, 30) for _ in range(16)]
    before = heap_in_use()
    for k in range(queries):
        v, t = meshes[k % len(meshes)]
        bvh = fcl.BVHModel()
        bvh.beginModel(t.shape[0], v.shape[0])
        bvh.addSubModel(v, t)
        bvh.endModel()
        if with_object:
            fcl.CollisionObject(bvh, fcl.Transform())
    return queries, heap_in_use() - before


def probe_contact(steps: int) -> tuple[int, int]:
    from tissue_sim_ros.core.contact import collision  # noqa: PLC0415
    from tissue_sim_ros.core.sim.scene import build_simulation  # noqa: PLC0415
    from tissue_sim_ros.core.sim.simulation import ToolPose  # noqa: PLC0415
    from tissue_sim_ros.core.timing import trajectories  # noqa: PLC0415

    tool = trajectories.B_TOOL
    sim = build_simulation({"tool_shape": tool.kind, "tool_length": tool.length, "tool_width": tool.width})
    calls = [0]
    distance = collision.fcl.distance

    def counted(*args):
        calls[0] += 1
        return distance(*args)

    collision.fcl.distance = counted
    try:
        # hover: the highest y (above the lower tissue's top, ~0.40 m) at which the contact still asks fcl
        y = 0.47
        while y > 0.40:
            sim.step(ToolPose(0.5, y, 0.0))
            calls[0] = 0
            for _ in range(5):
                sim.step(ToolPose(0.5, y, 0.0))
            if calls[0] >= 5:
                break
            y -= 0.002
        for _ in range(50):
            sim.step(ToolPose(0.5, y, 0.0))
        calls[0] = 0
        before = heap_in_use()
        for _ in range(steps):
            sim.step(ToolPose(0.5, y, 0.0))
        return calls[0], heap_in_use() - before
    finally:
        collision.fcl.distance = distance


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=20000, help="queries (steps for the contact row)")
    args = parser.parse_args()
    rows = [("contact (Simulation.step, tool in reach)", *probe_contact(args.queries)),
            ("CollisionObject per query", *probe_bare(args.queries, True)),
            ("BVHModel only (control)", *probe_bare(args.queries, False))]
    print(f"{'what':44s} {'queries':>8s} {'heap growth':>12s} {'bytes/query':>12s}")
    for name, n, grown in rows:
        print(f"{name:44s} {n:8d} {grown:12d} {grown / max(n, 1):12.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
