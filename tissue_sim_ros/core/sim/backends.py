"""Where sweeps run: this machine's cores (``local``) or a Ray cluster (``ray``), with the same results.

Two shapes of work:

* batch rollouts from a snapshot (:mod:`~tissue_sim_ros.core.sim.batch`):
  :func:`rollout_pool` gives a :class:`~tissue_sim_ros.core.sim.batch.RolloutPool`
  (local worker processes) or a :class:`RayRolloutPool` (one Ray actor per
  worker); both keep a scene's numba kernels warm in each worker, receive the
  scene once per worker and a snapshot once per batch, hand candidates to
  whichever worker is free, and return the same :class:`~tissue_sim_ros.core.sim.batch.BatchResult`,
  bit for bit;
* independent calls of one picklable function (``tissue-sim bench stability``'s
  runs, ``tissue-sim plan``'s insertions): :func:`map_calls`, over spawned
  local processes or Ray tasks, results in input order. Each worker process
  warms the kernels once (:func:`warm_kernels`) before its first call.

Ray is optional (``pip install '.[ray]'``); ``address`` is that of a running
cluster (``ray start --head`` prints it: ``HOST:6379``, or ``ray://HOST:10001``
for Ray Client), ``"local"`` starts a private single-node cluster, None
connects to ``RAY_ADDRESS`` or starts one. The package must be importable on
every node of the cluster (the same install there, or a ``runtime_env``).
"""
from __future__ import annotations

import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any, Callable, Sequence

import numpy as np

from ..contact.tool import Trajectory
from ..errors import InputError
from .batch import (
    BaselineTrack,
    BatchResult,
    BatchScene,
    CandidateResult,
    RolloutPool,
    ToolPath,
    finish,
    pool_paths,
    rollout_baseline,
    rollout_candidate,
)
from .simulation import Simulation
from .snapshot import SimSnapshot

BACKENDS = ("local", "ray")


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS`, or InputError naming it."""
    if backend not in BACKENDS:
        raise InputError(f"--backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    return backend


def check_jobs(jobs: int) -> int:
    """``jobs`` as a worker count, or InputError: a sweep needs at least one worker."""
    if jobs < 1:
        raise InputError(f"--jobs {jobs}: expected at least 1 worker")
    return int(jobs)


def import_ray() -> Any:
    """The ray module, or InputError saying how to install it."""
    try:
        import ray  # noqa: PLC0415
    except ImportError:
        raise InputError("--backend ray needs Ray: pip install 'tissue_sim_ros[ray]' (or pip install ray)") from None
    return ray


def init_ray(address: str | None = None, num_cpus: int | None = None) -> Any:
    """Connect to (or start) a Ray cluster once per process; the ray module.

    ``address="local"`` starts a single-node cluster bound to 127.0.0.1 without the dashboard.
    """
    ray = import_ray()
    if ray.is_initialized():
        return ray
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
    if address in (None, "", "local"):
        kwargs.update(address="local", _node_ip_address="127.0.0.1")
        if num_cpus is not None:
            kwargs["num_cpus"] = num_cpus
        if address is None and os.environ.get("RAY_ADDRESS"):
            kwargs = {"address": os.environ["RAY_ADDRESS"], "log_to_driver": False}
    else:
        kwargs = {"address": address, "log_to_driver": False}
    try:
        ray.init(**kwargs)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise InputError(f"--address {address!r}: could not connect to a Ray cluster there ({exc})") from None
    return ray


# --------------------------------------------------------------------------- batch rollouts on Ray actors


class _RolloutActor:
    """A Ray actor: one scene, built and warmed once; rolls candidates out from the batch's snapshot."""

    def __init__(self, scene: BatchScene) -> None:
        import numba  # noqa: PLC0415

        numba.set_num_threads(1)
        self.sim = scene.build_warm()
        self._track: tuple[int, BaselineTrack] | None = None

    def set_scene(self, scene: BatchScene) -> int:
        self.sim = scene.build_warm()
        self._track = None
        return os.getpid()

    def pid(self) -> int:
        return os.getpid()

    def _track_of(self, batch: int, snap: SimSnapshot) -> BaselineTrack:
        """The baseline track of batch ``batch`` (one batch kept: a new batch drops the previous one's)."""
        if self._track is None or self._track[0] != batch:
            self._track = (batch, BaselineTrack(self.sim, snap))
        return self._track[1]

    def baseline(self, batch: int, snap: SimSnapshot, steps: int) -> np.ndarray:
        return rollout_baseline(self.sim, snap, steps, self._track_of(batch, snap))

    def run(self, batch: int, snap: SimSnapshot, path: ToolPath, index: int, keep: bool) -> CandidateResult:
        return rollout_candidate(self.sim, snap, path, index, keep, self._track_of(batch, snap))


class RayRolloutPool:
    """:class:`~tissue_sim_ros.core.sim.batch.RolloutPool`'s interface on Ray actors (one CPU each).

    Parameters
    ----------
    scene : BatchScene or Simulation
        Put in the object store once and given to every actor.
    workers : int, optional
        Actors (default: the cluster's CPUs).
    address : str, optional
        See :func:`init_ray`.
    """

    def __init__(self, scene: BatchScene | Simulation, workers: int | None = None, *,
                 address: str | None = None) -> None:
        ray = init_ray(address)
        self._ray = ray
        self.scene = BatchScene.from_simulation(scene) if isinstance(scene, Simulation) else scene
        self.scene_key = self.scene.key
        workers = int(ray.cluster_resources().get("CPU", 1)) if workers is None else workers
        if workers < 1:
            raise InputError(f"workers={workers}: expected at least 1 Ray actor")
        self.n_workers = workers
        actor = ray.remote(num_cpus=1)(_RolloutActor)
        scene_ref = ray.put(self.scene)
        self._actors = [actor.remote(scene_ref) for _ in range(workers)]
        self._batch = 0
        self.pids = ray.get([a.pid.remote() for a in self._actors])

    @property
    def alive(self) -> bool:
        return bool(self._actors)

    def __enter__(self) -> "RayRolloutPool":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def set_scene(self, scene: BatchScene | Simulation) -> None:
        self.scene = BatchScene.from_simulation(scene) if isinstance(scene, Simulation) else scene
        self.scene_key = self.scene.key
        ref = self._ray.put(self.scene)
        self._ray.get([a.set_scene.remote(ref) for a in self._actors])

    def run(self, snap: SimSnapshot, candidates: Sequence[ToolPath | Trajectory | np.ndarray], *,
            final_state: bool = False, baseline: bool = True) -> BatchResult:
        """As :meth:`RolloutPool.run`: the same numbers, bit for bit."""
        ray = self._ray
        if not self._actors:
            raise RuntimeError("the Ray rollout pool is closed")
        t0 = time.perf_counter()
        paths = pool_paths(self.scene, self.scene_key, snap, candidates)
        snap_ref = ray.put(snap)  # once per batch, shared by every actor
        self._batch += 1
        batch = self._batch
        tasks: list[tuple] = [("baseline", max(p.n_steps for p in paths))] if baseline else []
        tasks += [("run", i, p) for i, p in enumerate(paths)]
        pending: dict[Any, tuple[int, tuple]] = {}
        next_task = 0

        def submit(a: int) -> None:
            nonlocal next_task
            task = tasks[next_task]
            next_task += 1
            actor = self._actors[a]
            ref = (actor.baseline.remote(batch, snap_ref, task[1]) if task[0] == "baseline"
                   else actor.run.remote(batch, snap_ref, task[2], task[1], final_state))
            pending[ref] = (a, task)

        for _ in range(2):  # two in flight per actor: none waits for the driver's round trip
            for a in range(self.n_workers):
                if next_task < len(tasks):
                    submit(a)
        results: list[CandidateResult | None] = [None] * len(paths)
        energy = None  # the baseline's
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            a, task = pending.pop(done[0])
            value = ray.get(done[0])
            if task[0] == "baseline":
                energy = value
            else:
                results[task[1]] = value
            if next_task < len(tasks):
                submit(a)
        assert energy is not None or not baseline
        out = [finish(r, energy) for r in results if r is not None]
        return BatchResult(out, np.zeros(0) if energy is None else energy, time.perf_counter() - t0, self.n_workers)

    def close(self) -> None:
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []


def rollout_pool(scene: BatchScene | Simulation, workers: int | None = None, backend: str = "local",
                 address: str | None = None) -> RolloutPool | RayRolloutPool:
    """A pool of warm rollout workers on this machine or on Ray."""
    if check_backend(backend) == "ray":
        return RayRolloutPool(scene, workers, address=address)
    return RolloutPool(scene, workers)


# --------------------------------------------------------------------------- independent calls


def warm_kernels() -> None:
    """Load (or compile) the solver and contact kernels once in this process: a tiny scene stepped with a tool."""
    from ..config import resolve_config  # noqa: PLC0415
    from ..mesh import mesh_rectangle  # noqa: PLC0415

    for contact in ("paper", "projection"):
        cfg = resolve_config({"contact_model": contact, "boundary_y_bottom": 0.001, "boundary_y_top": math.nan,
                              "tool_shape": "box", "tool_length": 0.1}, source="warm_kernels")
        Simulation.from_config(cfg, mesh=mesh_rectangle(0.2, 0.1, 0.05)).warm_up()


def _local_init() -> None:
    import numba  # noqa: PLC0415

    numba.set_num_threads(1)
    warm_kernels()


def map_calls(fn: Callable[..., Any], calls: Sequence[tuple], *, backend: str = "local", workers: int | None = None,
              address: str | None = None, progress: Callable[[], None] | None = None) -> list[Any]:
    """``[fn(*args) for args in calls]`` on worker processes (local) or Ray tasks, in input order.

    ``workers=1`` with the local backend runs in this process. ``progress`` is called once per finished call.
    """
    check_backend(backend)
    if backend == "local":
        workers = (os.cpu_count() or 1) if workers is None else workers
        if workers < 1:
            raise InputError(f"--jobs {workers}: expected at least 1 worker")
        if workers == 1:
            out = []
            for args in calls:
                out.append(fn(*args))
                if progress:
                    progress()
            return out
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"), initializer=_local_init) as pool:
            futures = [pool.submit(fn, *args) for args in calls]
            out = []
            for f in futures:
                out.append(f.result())
                if progress:
                    progress()
            return out
    ray = init_ray(address)
    remote = ray.remote(num_cpus=1)(_ray_call)
    refs = [remote.remote(fn, args) for args in calls]
    out = []
    for ref in refs:
        out.append(ray.get(ref))
        if progress:
            progress()
    return out


_WARM = {"done": False}


def _ray_call(fn: Callable[..., Any], args: tuple) -> Any:
    """A Ray task: the worker process warms the kernels before its first call (Ray reuses worker processes)."""
    if not _WARM["done"]:
        import numba  # noqa: PLC0415

        numba.set_num_threads(1)
        warm_kernels()
        _WARM["done"] = True
    return fn(*args)
