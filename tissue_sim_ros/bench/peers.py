"""``tissue-sim bench peers``: time per step against what a user might pick instead, in one run.

Same strip meshes (about 500, 2k, 8k and 20k particles), pinned along the bottom
row, falling under gravity from rest, 30 iterations, XPBD stiffnesses of
``config/tissue_sim.yaml``:

* **ours**: :class:`~tissue_sim_ros.core.physics.solvers.Solver`, XPBD Gauss-Seidel
  as it runs by default (serial), and with ``parallel=True`` (partitioned on
  all threads: an explicit option, see ``PARALLEL_MIN_PARTICLES``), stepped by a
  :class:`~tissue_sim_ros.core.sim.simulation.Simulation` and timed by its
  report's ``timings["solve"]`` (the solver's step alone);
* **NumPy**: the vectorised Jacobi baseline (:mod:`~tissue_sim_ros.bench.numpy_baseline`);
* **Taichi** (optional, ``pip install taichi``): the identical algorithm
  (prediction, per-step multipliers, serial Gauss-Seidel over all edges then
  all triangles, velocity update) written here as Taichi kernels on the CPU;
  checked against ours on the first step;
* **MuJoCo** (optional, ``pip install mujoco``): a 2D flex (``dof="2d"``)
  with edge equality constraints on the same vertices and triangles, the
  bottom row pinned, solver CG with the same iteration count (tolerance 0,
  so every iteration runs). MuJoCo solves a different model: soft equality
  constraints on edge lengths (no area constraint), its own constraint
  solver and integrator; only the cost per step is comparable.

With ``--fem``: the peers on the same FEM problem instead, run to rest, errors against the scikit-fem
reference and wall time to rest (:mod:`~tissue_sim_ros.bench.peers_fem`).

Peers are imported only when installed; missing ones are reported and
skipped. Writes ``peers.csv`` and ``peers.png`` and prints ms per step and
each peer's time relative to ours (> 1: ours is faster), all from this run.
"""
# no "from __future__ import annotations": Taichi reads kernel argument annotations as objects
import functools
import importlib.util
import math
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core.config import Config, method_options, resolve_config
from ..core.mesh import TissueMesh, mesh_rectangle
from ..core.physics.model import Model
from ..core.sim.simulation import Simulation
from .accuracy import format_table, write_csv

#: strip spacing -> 496 / 2016 / 8064 / 20301 particles on a 1 m x 0.5 m strip
SIZES = {"500": 1 / 30, "2k": 1 / 62, "8k": 1 / 125, "20k": 1 / 200}


def strip_config() -> Config:
    """The benchmark's parameters: the shipped ones with XPBD Gauss-Seidel, 30 iterations of one substep, the
    bottom row pinned (a line at y = 1e-9 m) and no top line."""
    return resolve_config({**method_options("xpbd", 30), "boundary_y_bottom": 1e-9, "boundary_y_top": math.nan},
                          source="bench peers")


def strip(spacing: float) -> tuple[TissueMesh, Model]:
    """The benchmark strip and its XPBD model (bottom row pinned, :func:`strip_config`)."""
    mesh = mesh_rectangle(1.0, 0.5, spacing)
    return mesh, Model.from_mesh(mesh, strip_config().sim)


def _median_ms(step: Callable[[], None], n_steps: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        step()
    times = []
    for _ in range(n_steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


# ----------------------------------------------------------------------------- ours and NumPy


def _median_solve_ms(sim: Simulation, n_steps: int, warmup: int = 2) -> float:
    """Median of the solver's time per step [ms] (``timings["solve"]``) over ``n_steps`` tool-free steps of ``sim``,
    after ``warmup`` untimed ones."""
    for _ in range(warmup):
        sim.step()
    return 1e3 * float(np.median([sim.step().timings["solve"] for _ in range(n_steps)]))


def time_ours(model: Model, n_steps: int, parallel: bool | None) -> tuple[float, np.ndarray]:
    """Median ms per step of our XPBD Gauss-Seidel, and the positions after the first step."""
    from ..core.physics.solvers import Solver  # noqa: PLC0415

    sim = Simulation(model, solver=functools.partial(Solver, parallel=parallel))
    sim.step()
    first = sim.state.particle_q.copy()
    return _median_solve_ms(sim, n_steps), first


def time_numpy(model: Model, n_steps: int) -> float:
    """Median ms per step of the vectorised NumPy Jacobi baseline (XPBD, same iterations)."""
    from .numpy_baseline import NumpyJacobiSolver  # noqa: PLC0415

    sim = Simulation(model.with_params(model.params.with_(scheme="jacobi")), solver=NumpyJacobiSolver)
    return _median_solve_ms(sim, n_steps, warmup=1)


# ----------------------------------------------------------------------------- Taichi


class TaichiXPBD:
    """XPBD Gauss-Seidel written as Taichi kernels: the algorithm of our Solver, serial sweeps in mesh order."""

    def __init__(self, model: Model) -> None:
        import taichi as ti  # noqa: PLC0415

        self.ti = ti
        p = model.params
        n, ne, nt = model.n_particles, model.n_edges, model.n_triangles
        f64 = ti.f64
        self.x = ti.Vector.field(2, f64, n)
        self.v = ti.Vector.field(2, f64, n)
        self.x_old = ti.Vector.field(2, f64, n)
        self.w = ti.field(f64, n)
        self.edges = ti.Vector.field(2, ti.i32, ne)
        self.rest = ti.field(f64, ne)
        self.lam_e = ti.field(f64, ne)
        self.tris = ti.Vector.field(3, ti.i32, nt)
        self.area0 = ti.field(f64, nt)
        self.lam_t = ti.field(f64, nt)
        self.x.from_numpy(np.ascontiguousarray(model.particle_q0))
        self.v.from_numpy(np.zeros((n, 2)))
        self.w.from_numpy(np.ascontiguousarray(model.particle_inv_mass))
        self.edges.from_numpy(np.ascontiguousarray(model.edge_indices, dtype=np.int32))
        self.rest.from_numpy(np.ascontiguousarray(model.edge_rest_length))
        self.tris.from_numpy(np.ascontiguousarray(model.tri_indices, dtype=np.int32))
        self.area0.from_numpy(np.ascontiguousarray(model.tri_rest_area))
        self.dt = p.dt
        self.gravity = p.gravity
        self.iterations = p.iterations
        self.alpha_e = 1.0 / (p.stiffness_spring * p.dt * p.dt)
        self.alpha_t = 1.0 / (p.stiffness_area * p.dt * p.dt)
        self._step = self._build()

    def _build(self) -> Callable[..., None]:
        ti = self.ti
        x, v, x_old, w = self.x, self.v, self.x_old, self.w
        edges, rest, lam_e, tris, area0, lam_t = self.edges, self.rest, self.lam_e, self.tris, self.area0, self.lam_t

        @ti.kernel
        def step(dt: ti.f64, gravity: ti.f64, iterations: ti.i32, alpha_e: ti.f64, alpha_t: ti.f64):
            for i in x:  # prediction (independent per particle: parallel is fine)
                x_old[i] = x[i]
                if w[i] > 0.0:
                    v[i][1] += dt * gravity
                    x[i] += dt * v[i]
            for e in lam_e:
                lam_e[e] = 0.0
            for t in lam_t:
                lam_t[t] = 0.0
            ti.loop_config(serialize=True)
            for _ in range(iterations):  # Gauss-Seidel: everything below runs in order on one thread
                for e in range(edges.shape[0]):
                    i, j = edges[e][0], edges[e][1]
                    wsum = w[i] + w[j]
                    d = x[i] - x[j]
                    length = d.norm()
                    if wsum > 0.0 and length > 1e-15:
                        c = length - rest[e]
                        dlam = (-c - alpha_e * lam_e[e]) / (wsum + alpha_e)
                        lam_e[e] += dlam
                        n = d / length
                        x[i] += w[i] * dlam * n
                        x[j] -= w[j] * dlam * n
                for t in range(tris.shape[0]):
                    a, b, c3 = tris[t][0], tris[t][1], tris[t][2]
                    e1 = x[b] - x[a]
                    e2 = x[c3] - x[a]
                    c = 0.5 * (e1[0] * e2[1] - e1[1] * e2[0]) - area0[t]
                    gb = 0.5 * ti.Vector([e2[1], -e2[0]])
                    gc = 0.5 * ti.Vector([-e1[1], e1[0]])
                    ga = -(gb + gc)
                    den = w[a] * ga.norm_sqr() + w[b] * gb.norm_sqr() + w[c3] * gc.norm_sqr() + alpha_t
                    if den > 0.0:
                        dlam = (-c - alpha_t * lam_t[t]) / den
                        lam_t[t] += dlam
                        x[a] += w[a] * dlam * ga
                        x[b] += w[b] * dlam * gb
                        x[c3] += w[c3] * dlam * gc
            for i in x:  # velocity update
                v[i] = (x[i] - x_old[i]) / dt

        return step

    def step(self) -> None:
        self._step(self.dt, self.gravity, self.iterations, self.alpha_e, self.alpha_t)
        self.ti.sync()

    def positions(self) -> np.ndarray:
        return self.x.to_numpy()


def time_taichi(model: Model, n_steps: int) -> tuple[float, np.ndarray]:
    """Median ms per step of the Taichi version, and its positions after the first step."""
    import taichi as ti  # noqa: PLC0415

    ti.init(arch=ti.cpu, default_fp=ti.f64, log_level=ti.ERROR)
    sim = TaichiXPBD(model)
    sim.step()
    first = sim.positions()
    return _median_ms(sim.step, n_steps), first


# ----------------------------------------------------------------------------- MuJoCo


def mujoco_xml(model: Model) -> str:
    """A 2D flex (dof="2d") on the model's vertices and triangles, edge equality constraints, bottom row pinned.

    Contacts are disabled (the strip touches nothing; MuJoCo's flex collision arena otherwise overflows
    from ~2k vertices).
    """
    p = model.params
    v = model.particle_q0
    points = " ".join(f"{x:.9g} {y:.9g} 0" for x, y in v)
    elements = " ".join(str(int(i)) for i in model.tri_indices.ravel())
    pinned = " ".join(str(int(i)) for i in np.flatnonzero(model.particle_pinned))
    total_mass = p.mass * model.n_particles
    return f"""
<mujoco>
  <option timestep="{p.dt}" solver="CG" iterations="{p.iterations}" tolerance="0" gravity="0 {p.gravity} 0">
    <flag contact="disable"/>
  </option>
  <size memory="1G"/>
  <worldbody>
    <flexcomp name="tissue" type="direct" dim="2" dof="2d" point="{points}" element="{elements}"
              mass="{total_mass}" radius="0.001">
      <edge equality="true"/>
      <contact contype="0" conaffinity="0" selfcollide="none"/>
      <pin id="{pinned}"/>
    </flexcomp>
  </worldbody>
</mujoco>"""


def time_mujoco(model: Model, n_steps: int) -> float:
    """Median ms per step of MuJoCo's 2D flex on the same mesh (mj_step, CG, same iteration count)."""
    import mujoco  # noqa: PLC0415

    m = mujoco.MjModel.from_xml_string(mujoco_xml(model))
    d = mujoco.MjData(m)
    return _median_ms(lambda: mujoco.mj_step(m, d), n_steps)


# ----------------------------------------------------------------------------- the command


def available(name: str) -> bool:
    """True if a peer's package can be imported."""
    return importlib.util.find_spec(name) is not None


def run(out: str | Path, *, quick: bool = False, steps: int = 30, fem: bool = False) -> int:
    """Time ours and every installed peer on the strips; print the table, write peers.csv/png into ``out``; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    quick : bool
        The smallest mesh, few steps (smoke test).
    steps : int
        Timed steps per measurement (median; ``quick``: at most 5).
    fem : bool
        Instead: the peers on the same FEM problem, run to rest (:func:`~tissue_sim_ros.bench.peers_fem.run_fem`).
    """
    from tqdm import tqdm  # noqa: PLC0415

    from ..core.errors import InputError  # noqa: PLC0415

    if steps < 1:
        raise InputError(f"--steps={steps}: expected at least 1 timed step")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if fem:
        from .peers_fem import run_fem  # noqa: PLC0415

        for name, pkg in (("mujoco", "mujoco"), ("newton", "newton")):
            if not available(pkg):
                print(f"{name} is not installed: skipped (pip install '.[peers]')")
        return run_fem(out, quick, available("mujoco"), available("newton") and available("warp"))
    sizes = {"500": SIZES["500"]} if quick else SIZES
    n_steps = min(steps, 5) if quick else steps
    have = {name: available(name) for name in ("taichi", "mujoco")}
    for name, ok in have.items():
        if not ok:
            print(f"{name} is not installed: skipped (pip install '.[peers]')")
    rows: list[dict[str, Any]] = []
    jobs = [(label, sp) for label, sp in sizes.items()]
    for label, spacing in tqdm(jobs, desc="peers", unit="mesh", dynamic_ncols=True):
        mesh, model = strip(spacing)
        row: dict[str, Any] = {"size": label, "particles": model.n_particles, "edges": model.n_edges,
                               "triangles": model.n_triangles, "iterations": model.params.iterations}
        row["ours_ms"], ours_first = time_ours(model, n_steps, None)
        row["ours_parallel_ms"], _ = time_ours(model, n_steps, True)
        row["parallel_speedup"] = row["ours_ms"] / row["ours_parallel_ms"]
        row["numpy_jacobi_ms"] = time_numpy(model, max(3, n_steps // 3))
        row["taichi_ms"] = row["taichi_max_diff_m"] = math.nan
        if have["taichi"]:
            row["taichi_ms"], taichi_first = time_taichi(model, n_steps)
            row["taichi_max_diff_m"] = float(np.abs(taichi_first - ours_first).max())
        row["mujoco_ms"] = time_mujoco(model, n_steps) if have["mujoco"] else math.nan
        for peer in ("numpy_jacobi", "taichi", "mujoco"):
            row[f"{peer}_over_ours"] = row[f"{peer}_ms"] / row["ours_ms"]
        rows.append(row)
    write_csv(out / "peers.csv", rows)
    _plot(out / "peers.png", rows)
    print("\nms per step (median), 30 iterations, XPBD; ratio = peer / ours (> 1: ours faster):")
    print(format_table(rows, ["size", "particles", "ours_ms", "ours_parallel_ms", "parallel_speedup", "taichi_ms",
                              "mujoco_ms", "numpy_jacobi_ms", "taichi_over_ours", "mujoco_over_ours",
                              "numpy_jacobi_over_ours"]))
    if have["taichi"]:
        print("Taichi vs ours after the first step: max |dx| = "
              + ", ".join(f"{r['taichi_max_diff_m']:.2g} m" for r in rows))
    print(f"\nwrote {out / 'peers.csv'} and {out / 'peers.png'}")
    return 0


def _plot(path: Path, rows: list[dict[str, Any]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7, 4.5))
    n = [r["particles"] for r in rows]
    for key, label in (("ours_ms", "ours (numba, serial: the default)"), ("ours_parallel_ms", "ours, parallel=True"),
                       ("taichi_ms", "Taichi, same algorithm (serial GS)"), ("mujoco_ms", "MuJoCo 2D flex, CG"),
                       ("numpy_jacobi_ms", "NumPy Jacobi baseline")):
        y = [r[key] for r in rows]
        if any(math.isfinite(v) for v in y):
            ax.plot(n, y, marker="o", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("particles")
    ax.set_ylabel("median ms per step (30 iterations)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
