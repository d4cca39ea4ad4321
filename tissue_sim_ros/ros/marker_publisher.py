"""``tissue/markers`` encoded and published off the step thread, newest state only.

A 5,000-triangle MarkerArray is about 1 MB: encoding it is quick, but handing
1 MB to DDS every step is what made the node miss its ticks. The step thread
therefore only copies what the markers need (particle positions, the tool
pose, the contact particles: a few hundred kB of memcpy) into a one-slot
mailbox; a worker thread encodes the newest snapshot and publishes it. When
the worker is still busy with the previous one, the new snapshot replaces the
waiting one (``skipped`` counts these): the viewer sees the newest state, the
step never waits.

The worker runs at a lower priority than the step thread (``nice``, added to
its own niceness: Linux schedules threads, and raising a niceness needs no
privileges): when the node shares its cores with other work, the scheduler
then gives the core to the step first and the markers take what is left
(docs/benchmarks/node.md: fewer missed ticks at +10 than at the step's priority).

The worker holds no ROS objects of its own: it calls the ``publish`` it was
given (an rclpy publisher's, thread-safe in rcl) with the encoded bytes.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .messages import SceneEncoder, Stamp
from .realtime import nice_this_thread


@dataclass
class MarkerSnapshot:
    """What one MarkerArray shows: copies, so the step thread may go on changing its own arrays."""

    encoder: SceneEncoder
    stamp: Stamp
    frame_id: str
    q: np.ndarray
    tool_pose: tuple[float, float, float] | None = None
    tool_stamp: Stamp | None = None
    contact_particles: np.ndarray | None = None
    grasped_particles: np.ndarray | None = None
    """Particles a grasper holds (None: none)."""
    strain: np.ndarray | None = None
    """Per-particle strain if the step thread computed it already (None: the worker computes it)."""

    def encode(self) -> bytes:
        strain = self.strain if self.strain is not None else self.encoder.vertex_strain(self.q)
        return self.encoder.markers(self.stamp, self.frame_id, self.q, strain, tool_pose=self.tool_pose,
                                    tool_stamp=self.tool_stamp, contact_particles=self.contact_particles,
                                    grasped_particles=self.grasped_particles)


class MarkerPublisher:
    """A worker thread with a latest-only slot: :meth:`submit` never blocks on encoding or DDS.

    Parameters
    ----------
    publish : callable
        Called on the worker thread with the encoded CDR bytes of each MarkerArray.
    on_error : callable, optional
        Called on the worker thread with an exception raised while encoding or
        publishing (the worker goes on with the next snapshot).
    nice : int, optional
        Added to the worker thread's niceness (0: as the thread that made it;
        Linux only: elsewhere a niceness is the whole process's, left alone).
    """

    def __init__(self, publish: Callable[[bytes], None],
                 on_error: Callable[[BaseException], None] | None = None, nice: int = 0) -> None:
        self._publish = publish
        self._on_error = on_error
        self._nice = nice
        self.niceness: int | None = None
        """The worker thread's niceness once it runs (None: not read, or not Linux)."""
        self._cond = threading.Condition()
        self._slot: MarkerSnapshot | None = None
        self._busy = False
        self._closed = False
        self.submitted = 0
        self.published = 0
        self.skipped = 0
        """Snapshots replaced in the slot before the worker took them."""
        self.errors = 0
        self.encode_seconds = 0.0
        """Wall time the worker spent encoding and publishing (cumulative) [s]."""
        self._thread = threading.Thread(target=self._run, name="tissue_markers", daemon=True)
        self._thread.start()

    def submit(self, snapshot: MarkerSnapshot) -> None:
        """Hand over the newest snapshot (replacing one the worker has not taken yet)."""
        with self._cond:
            if self._closed:
                return
            if self._slot is not None:
                self.skipped += 1
            self._slot = snapshot
            self.submitted += 1
            self._cond.notify()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until the slot is empty and the worker idle (tests, shutdown); False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._slot is None and not self._busy, timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Publish what is waiting, then stop the worker (idempotent)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)

    def _lower_priority(self) -> None:
        try:
            self.niceness = nice_this_thread(self._nice)
        except OSError as exc:  # a sandbox may forbid it: the markers then run as before
            if self._on_error is not None:
                self._on_error(exc)

    def _run(self) -> None:
        self._lower_priority()
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._slot is not None or self._closed)
                snapshot, self._slot = self._slot, None
                if snapshot is None:  # closed and nothing left
                    self._cond.notify_all()
                    return
                self._busy = True
            t0 = time.perf_counter()
            try:
                self._publish(snapshot.encode())
                self.published += 1
            except Exception as exc:  # noqa: BLE001  a worker must outlive one bad snapshot
                self.errors += 1
                if self._on_error is not None:
                    self._on_error(exc)
            finally:
                self.encode_seconds += time.perf_counter() - t0
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
