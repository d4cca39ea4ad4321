"""The rollout pool: persistent worker processes that roll candidates out, the same numbers as the serial path.

Spawned workers, each with the scene built and its numba kernels loaded and warmed once, the scene sent once per
worker and a snapshot once per batch per worker. Candidates are handed out one at a time to whichever worker is
free (two in flight per worker so none waits for the parent), so a batch ends when its last candidate does. Each
worker runs :func:`~tissue_sim_ros.core.sim.batch.rollout_candidate`, :func:`~tissue_sim_ros.core.sim.batch.finish`
and :class:`~tissue_sim_ros.core.sim.batch.BaselineTrack`, the serial path's own (``test/test_batch.py``
compares them with ``np.array_equal``).
"""
from __future__ import annotations

import os
import time
import traceback
from multiprocessing import get_context
from multiprocessing.connection import Connection, wait
from typing import Any, Sequence

import numpy as np

from ..contact.tool import Trajectory
from ..errors import InputError
from .batch import (
    BaselineTrack,
    BatchResult,
    BatchScene,
    CandidateResult,
    ToolPath,
    finish,
    pool_paths,
    rollout_baseline,
    rollout_candidate,
)
from .simulation import Simulation
from .snapshot import SimSnapshot


def _worker_main(conn: Connection, scene: BatchScene) -> None:
    """A worker: build and warm the scene once, then serve snapshots, baselines and candidates until told to stop."""
    import signal  # noqa: PLC0415

    import numba  # noqa: PLC0415

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent stops us
    numba.set_num_threads(1)  # one core per worker: the workers are the parallelism
    try:
        sim = scene.build_warm()
        conn.send(("ready", os.getpid()))
    except Exception:  # noqa: BLE001  reported to the parent, which raises it
        conn.send(("error", -1, -1, traceback.format_exc()))
        return
    tracks: dict[int, BaselineTrack] = {}
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        kind = msg[0]
        if kind == "stop":
            return
        try:
            if kind == "scene":
                sim = msg[1].build_warm()
                tracks.clear()
                conn.send(("scene", os.getpid()))
            elif kind == "snapshot":
                tracks.clear()
                tracks[msg[1]] = BaselineTrack(sim, msg[2])
            elif kind == "baseline":
                _, batch, steps = msg
                track = tracks[batch]
                conn.send(("baseline", batch, -1, rollout_baseline(sim, track.snap, steps, track)))
            elif kind == "run":
                _, batch, index, path, keep = msg
                track = tracks[batch]
                conn.send(("result", batch, index, rollout_candidate(sim, track.snap, path, index, keep, track)))
        except Exception:  # noqa: BLE001
            conn.send(("error", msg[1] if len(msg) > 1 else -1, msg[2] if len(msg) > 2 else -1, traceback.format_exc()))


class RolloutPool:
    """Persistent worker processes that keep a scene's kernels warm and roll candidates out on demand.

    Parameters
    ----------
    scene : BatchScene or Simulation
        Sent to every worker once (and again by :meth:`set_scene`).
    workers : int
        Worker processes (default: the machine's cores).
    nice : int
        Added to each worker's niceness, so that a process sharing the cores
        (the node's step thread) is scheduled first; 0 = unchanged.
    start_timeout : float
        Seconds to wait for the workers to build and warm the scene.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, scene: BatchScene | Simulation, workers: int | None = None, *, nice: int = 0,
                 start_timeout: float = 120.0) -> None:
        self.scene = BatchScene.from_simulation(scene) if isinstance(scene, Simulation) else scene
        workers = (os.cpu_count() or 1) if workers is None else workers
        if workers < 1:
            raise InputError(f"workers={workers}: expected at least 1 worker process")
        self.n_workers = int(workers)
        self.scene_key = self.scene.key
        ctx = get_context("spawn")  # a fresh interpreter: numba's threads do not survive fork
        self._conns: list[Connection] = []
        self._procs = []
        self._batch = 0
        for _ in range(self.n_workers):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker_main, args=(child, self.scene), daemon=True)
            proc.start()
            child.close()
            if nice:
                # at once, before the worker's imports compete with the caller's threads
                try:
                    os.setpriority(os.PRIO_PROCESS, proc.pid, os.getpriority(os.PRIO_PROCESS, proc.pid) + nice)
                except OSError:
                    pass
            self._conns.append(parent)
            self._procs.append(proc)
        self.pids = [self._expect(c, "ready", start_timeout) for c in self._conns]

    def _expect(self, conn: Connection, kind: str, timeout: float) -> Any:
        if not conn.poll(timeout):
            self.close()
            raise RuntimeError(f"rollout worker did not answer '{kind}' within {timeout} s")
        try:
            msg = conn.recv()
        except EOFError:
            msg = ("error", -1, -1, "the worker exited before it was ready (is the caller's main module import-safe?)")
        if msg[0] != kind:
            self.close()
            raise RuntimeError(f"rollout worker failed:\n{msg[-1]}")
        return msg[1]

    def __enter__(self) -> "RolloutPool":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    @property
    def alive(self) -> bool:
        return bool(self._procs) and all(p.is_alive() for p in self._procs)

    def set_scene(self, scene: BatchScene | Simulation, timeout: float = 120.0) -> None:
        """Send a new scene (other parameters or mesh) to every worker; they rebuild and warm it."""
        self.scene = BatchScene.from_simulation(scene) if isinstance(scene, Simulation) else scene
        self.scene_key = self.scene.key
        for c in self._conns:
            c.send(("scene", self.scene))
        for c in self._conns:
            self._expect(c, "scene", timeout)

    def run(self, snap: SimSnapshot, candidates: Sequence[ToolPath | Trajectory | np.ndarray], *,
            final_state: bool = False, baseline: bool = True) -> BatchResult:
        """Roll every candidate out from ``snap`` on the workers (see :func:`rollout_batch`)."""
        if not self.alive:
            raise RuntimeError("the rollout pool is closed or a worker died")
        t0 = time.perf_counter()
        paths = pool_paths(self.scene, self.scene_key, snap, candidates)
        self._batch += 1
        batch = self._batch
        for c in self._conns:
            c.send(("snapshot", batch, snap))
        # the baseline first (it is as long as the longest candidate), then candidates in order
        tasks: list[tuple] = [("baseline", batch, max(p.n_steps for p in paths))] if baseline else []
        tasks += [("run", batch, i, p, final_state) for i, p in enumerate(paths)]
        results: list[CandidateResult | None] = [None] * len(paths)
        energy: np.ndarray | None = None  # the baseline's
        next_task = 0
        in_flight = {id(c): 0 for c in self._conns}
        by_id = {id(c): c for c in self._conns}
        for _ in range(2):  # two in flight per worker: a worker never waits for the parent's round trip
            for c in self._conns:
                if next_task < len(tasks):
                    c.send(tasks[next_task])
                    in_flight[id(c)] += 1
                    next_task += 1
        remaining = len(tasks)
        while remaining:
            ready = wait([c for c in self._conns if in_flight[id(c)]], timeout=60.0)
            if not ready:
                if not self.alive:
                    raise RuntimeError("a rollout worker died")
                continue
            for c in ready:
                try:
                    msg = c.recv()
                except EOFError:
                    raise RuntimeError("a rollout worker died") from None
                kind, b, index, payload = msg
                if kind == "error":
                    raise RuntimeError(f"rollout worker failed on task {index}:\n{payload}")
                if b != batch:
                    continue
                in_flight[id(c)] -= 1
                remaining -= 1
                if kind == "baseline":
                    energy = payload
                else:
                    results[index] = payload
                if next_task < len(tasks):
                    by_id[id(c)].send(tasks[next_task])
                    in_flight[id(c)] += 1
                    next_task += 1
        assert energy is not None or not baseline
        out = [finish(r, energy) for r in results if r is not None]
        return BatchResult(out, np.zeros(0) if energy is None else energy, time.perf_counter() - t0, self.n_workers)

    def close(self) -> None:
        """Stop the workers (a second call does nothing)."""
        for c in self._conns:
            try:
                c.send(("stop",))
            except (OSError, BrokenPipeError):
                pass
        for p in self._procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join(timeout=2.0)
        for c in self._conns:
            c.close()
        self._conns, self._procs = [], []
