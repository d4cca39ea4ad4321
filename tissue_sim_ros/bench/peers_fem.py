"""``tissue-sim bench peers --fem``: peers on the same FEM problem, run to rest, side by side in one run.

The hanging strip of ``bench refinement`` (10 x 4 cm, top edge pinned, gravity,
E 50 kPa, nu 0.45, 1 mm, 1000 kg/m^3) on the same ``mesh_rectangle`` meshes,
with the same lumped masses (a third of each triangle's area x density x
thickness per corner), the same viscous damping rate (30 1/s) and the same
rest criterion (every particle slower than 1e-6 m/s):

* **ours**: ``material: neo_hookean`` with its defaults (dt 2 ms, 10 substeps of 10 Gauss-Seidel
  iterations);
* **MuJoCo** (optional, ``pip install mujoco``, measured with 4.0): a ``flexcomp`` with ``dim="2"``
  ``dof="2d"`` and ``<elasticity young poisson thickness elastic2d="stretch">`` (MuJoCo's membrane).
  Pitfalls handled here: ``elastic2d`` defaults to ``none`` (no membrane stiffness at all); flexcomp's
  ``mass`` is spread equally over the points, so each vertex body's mass is set to its lumped mass after
  compiling; MuJoCo's implicit integrators no longer integrate flex elasticity (the compiler refuses),
  so ``integrator="discrete"``; a diverged state is silently reset by MuJoCo, so a run counts as stable
  only without ``mjWARN_BADQACC`` warnings and with finite positions. The damping is a per-dof damping
  m_i x 30 1/s. Each mesh runs at the largest stable time step of ``--mujoco-dts``.

Reported per peer and mesh: the relative errors of the mean and the largest sag against the FEM
(:mod:`~tissue_sim_ros.bench.fem_reference`), steps and wall time to rest, time per step. The wall
times are from this run, one after the other on the same machine.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.mesh import TissueMesh, mesh_rectangle
from . import fem_reference as fem
from . import refinement as rf

DAMPING = 30.0
REST_SPEED = 1e-6
MUJOCO_DTS = (1e-4, 2e-4, 5e-4, 1e-3, 2e-3)
SPACINGS = (0.01, 0.005, 0.0025)


def lumped_mass(mesh: TissueMesh, density: float, thickness: float) -> np.ndarray:
    """A third of each triangle's rest area x density x thickness per corner [kg], (N,)."""
    v, t = mesh.vertices, mesh.triangles
    e1, e2 = v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    m = np.zeros(len(v))
    np.add.at(m, t.ravel(), np.repeat(area / 3.0, 3))
    return m * density * thickness


def sag_errors(rest: np.ndarray, x: np.ndarray, mass: np.ndarray, ref: fem.FemSolution) -> dict[str, float]:
    u_y = x[:, 1] - rest[:, 1]
    mean = float(-(mass * u_y).sum() / mass.sum())
    return {"err_mean_sag": mean / ref.mean_sag - 1.0, "err_max_sag": float(-u_y.min()) / ref.max_sag - 1.0}


def mujoco_model(mesh: TissueMesh, dt: float, mass: np.ndarray):
    """The strip as a MuJoCo 2D flex membrane (see the module docstring), with lumped masses and damping."""
    import mujoco  # noqa: PLC0415

    m = rf.MATERIAL
    v = mesh.vertices
    pinned = np.flatnonzero(v[:, 1] > rf.HEIGHT - 1e-9)
    points = " ".join(f"{x:.9g} {y:.9g} 0" for x, y in v)
    elements = " ".join(str(int(i)) for i in mesh.triangles.ravel())
    xml = f"""<mujoco>
  <option timestep="{dt}" gravity="0 {-rf.GRAVITY} 0" integrator="discrete"><flag contact="disable"/></option>
  <size memory="1G"/>
  <worldbody>
    <flexcomp name="tissue" type="direct" dim="2" dof="2d" point="{points}" element="{elements}"
              mass="{mass.sum()}" radius="0.0005">
      <elasticity young="{m['young_modulus']}" poisson="{m['poisson_ratio']}" thickness="{m['thickness']}"
                  elastic2d="stretch"/>
      <contact contype="0" conaffinity="0" selfcollide="none"/>
      <pin id="{' '.join(map(str, pinned))}"/>
    </flexcomp>
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    body = model.flex_vertbodyid[:model.nflexvert]
    free = body > 0
    model.body_mass[body[free]] = mass[free]  # flexcomp spread the total equally
    for j in range(model.njnt):
        model.dof_damping[model.jnt_dofadr[j]] = DAMPING * model.body_mass[model.jnt_bodyid[j]]
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)
    return model, data


def mujoco_to_rest(mesh: TissueMesh, dt: float, mass: np.ndarray, max_time: float = 5.0) -> dict[str, Any]:
    """Run MuJoCo to rest; ``stable`` False when it warned of a bad acceleration (and reset) or went non-finite."""
    import mujoco  # noqa: PLC0415

    model, data = mujoco_model(mesh, dt, mass)
    n_max = int(max_time / dt)
    t0 = time.perf_counter()
    k = 0
    at_rest = False
    while k < n_max:
        mujoco.mj_step(model, data)
        k += 1
        if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0 or not np.all(np.isfinite(data.qvel)):
            break
        if k > 20 and float(np.abs(data.qvel).max()) < REST_SPEED:
            at_rest = True
            break
    wall = time.perf_counter() - t0
    stable = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0 and bool(np.all(np.isfinite(data.qpos)))
    return {"x": np.array(data.flexvert_xpos[:, :2]), "steps": k, "wall": wall, "stable": stable,
            "at_rest": at_rest and stable}


def ours_to_rest(mesh: TissueMesh) -> dict[str, Any]:
    from ..core.simulation import Simulation  # noqa: PLC0415

    cfg = rf._config("hanging_strip", 0.002, {}, DAMPING)
    sim = Simulation.from_config(cfg, mesh=mesh)
    rest = rf.run_to_rest(sim, None, REST_SPEED, 20000)
    return {"x": sim.state.particle_q.copy(), "steps": rest.steps, "wall": rest.wall, "stable": True,
            "at_rest": rest.at_rest, "dt": sim.params.dt, "sim": sim}


def compare(spacings: Sequence[float] = SPACINGS, mujoco_dts: Sequence[float] = MUJOCO_DTS,
            with_mujoco: bool = True) -> list[dict[str, Any]]:
    """Rows (one per peer and mesh) of errors against the FEM and wall time to rest."""
    ref = fem.hanging_strip()
    m = rf.MATERIAL
    rows = []
    for h in spacings:
        mesh = mesh_rectangle(rf.WIDTH, rf.HEIGHT, h)
        mass = lumped_mass(mesh, m["density"], m["thickness"])
        ours = ours_to_rest(mesh)
        rows.append({"peer": "ours", "spacing": h, "particles": len(mesh.vertices), "dt": ours["dt"],
                     **sag_errors(mesh.vertices, ours["x"], ours["sim"].model.particle_mass, ref),
                     "steps_to_rest": ours["steps"], "wall_to_rest_s": ours["wall"],
                     "us_per_step": 1e6 * ours["wall"] / ours["steps"], "at_rest": ours["at_rest"]})
        if not with_mujoco:
            continue
        best = None
        for dt in sorted(mujoco_dts, reverse=True):  # the largest stable time step first
            run = mujoco_to_rest(mesh, dt, mass)
            if run["at_rest"]:
                best = (dt, run)
                break
        if best is None:
            rows.append({"peer": "mujoco", "spacing": h, "particles": len(mesh.vertices), "dt": math.nan,
                         "err_mean_sag": math.nan, "err_max_sag": math.nan, "steps_to_rest": 0,
                         "wall_to_rest_s": math.nan, "us_per_step": math.nan, "at_rest": False})
            continue
        dt, run = best
        rows.append({"peer": "mujoco", "spacing": h, "particles": len(mesh.vertices), "dt": dt,
                     **sag_errors(mesh.vertices, run["x"], mass, ref), "steps_to_rest": run["steps"],
                     "wall_to_rest_s": run["wall"], "us_per_step": 1e6 * run["wall"] / run["steps"],
                     "at_rest": True})
    for r in rows:
        ours = next(o for o in rows if o["peer"] == "ours" and o["spacing"] == r["spacing"])
        r["wall_over_ours"] = r["wall_to_rest_s"] / ours["wall_to_rest_s"]
    return rows


def plot(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for peer, marker in (("ours", "o"), ("mujoco", "s")):
        sel = [r for r in rows if r["peer"] == peer and r["at_rest"]]
        if not sel:
            continue
        ax.loglog([r["wall_to_rest_s"] for r in sel], [abs(r["err_mean_sag"]) for r in sel], marker + "-",
                  label=f"{peer}: mean sag")
        for r in sel:
            ax.annotate(f"{1e3 * r['spacing']:g} mm", (r["wall_to_rest_s"], abs(r["err_mean_sag"])), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("wall time to rest [s]")
    ax.set_ylabel("|relative error| against the FEM")
    ax.set_title("hanging strip, run to rest: accuracy vs wall time", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_fem(out: Path, quick: bool, have_mujoco: bool) -> int:
    from .accuracy import format_table  # noqa: PLC0415

    spacings = (0.02, 0.01) if quick else SPACINGS
    rows = compare(spacings, (5e-4, 2e-4) if quick else MUJOCO_DTS, with_mujoco=have_mujoco)
    rf.write_csv(out / "peers_fem.csv", rows)
    plot(out / "peers_fem.png", rows)
    shown = [{**r, "err_mean_sag": f"{100 * r['err_mean_sag']:+.2f}%", "err_max_sag": f"{100 * r['err_max_sag']:+.2f}%"}
             for r in rows]
    print("hanging strip (10 x 4 cm, E 50 kPa, nu 0.45, 1 mm), run to rest, against the FEM (side by side):")
    print(format_table(shown, ["peer", "spacing", "particles", "dt", "err_mean_sag", "err_max_sag", "steps_to_rest",
                               "wall_to_rest_s", "us_per_step", "wall_over_ours", "at_rest"]))
    print(f"wrote {out / 'peers_fem.csv'} and {out / 'peers_fem.png'}")
    return 0 if all(r["at_rest"] for r in rows if r["peer"] == "ours") else 1
