"""``tissue-sim bench peers --fem``, contact part: a press and a two-body drop, ours beside MuJoCo.

Two scenes on the strip of ``bench contact``'s force smoothness (6 x 2 cm, 2.5 mm mesh, bottom row pinned,
E 50 kPa, nu 0.45, 5 mm thick, 1000 kg/m^3, gravity, damping 10 1/s, each particle's lumped mass):

* **press**: a capsule (segment 2 cm along x, radius 2.5 mm) from 1 mm above the centre pressed a third of the
  height deep at 1 cm/s, then held :data:`PRESS_HOLD` s. Reported at the end: the tissue's vertices inside the
  capsule where it really is and the deepest of them, the reaction on the tool |Fy| (mean over the last tenth of
  the hold), where the tool stopped short of its command;
* **drop**: a 4 x 1 cm block of the same material released 1 mm above the strip, :data:`DROP_TIME` s. Reported:
  the vertices of either body inside a triangle of the other (at the end and at most over the run) and the
  deepest (distance to the other body's boundary), the gap left between them at the end, the block's contact
  force over its weight (the mean over the last tenth).

Each with the wall time of the whole run and per step, one after the other in this process.

* **ours**: ``material: neo_hookean`` with its default step (``method: ipc``, barrier contact; friction 0) and
  the former default (``quasi_newton`` with ``projection`` contact: the tool only, bodies pass through each
  other), dt 10 ms;
* **MuJoCo** (optional, ``pip install mujoco``): each body a ``flexcomp`` (``dim="2" dof="2d"``, the membrane
  ``elastic2d="stretch"``, radius 0.1 mm, ``condim="1"``: frictionless as ours), the lumped masses and the
  damping as in :mod:`~tissue_sim_ros.bench.peers_fem`, the capsule a mocap body's ``capsule`` geom through the
  plane (its section the same stadium), dt 1 ms (``integrator="discrete"``). Its default soft contact
  (``mujoco``) and, where the version has it (``mjENBL_IPC``, MuJoCo >= 3.14), its experimental IPC mode
  (``mujoco_ipc``: ``<flag ipc="enable"/>``; frictionless, for dim-2 flexes). The contact forces are read from
  ``qfrc_constraint`` (the flexes have no other constraint: the pinned vertices have no dofs).

The measures are this module's own (:func:`inside_capsule`, :func:`overlap`), the same for every peer.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.mesh import TissueMesh, mesh_rectangle

WIDTH, HEIGHT, SPACING = 0.06, 0.02, 0.0025
BLOCK_W, BLOCK_H, BLOCK_GAP = 0.04, 0.01, 0.001
CAPSULE_LENGTH, CAPSULE_RADIUS = 0.02, 0.0025
YOUNG, NU, THICKNESS, DENSITY, GRAVITY, DAMPING = 50e3, 0.45, 0.005, 1000.0, 9.8, 10.0
PRESS_SPEED = 0.01
PRESS_HOLD = 0.5
DROP_TIME = 1.0
OURS_DT = 0.01
MUJOCO_DT = 1e-3
MUJOCO_RADIUS = 1e-4
#: ours: method name -> parameters
OURS = {"ours_ipc": {"method": "ipc", "contact_model": "barrier"},
        "ours_former": {"method": "quasi_newton", "contact_model": "projection"}}


def strip_mesh() -> TissueMesh:
    return mesh_rectangle(WIDTH, HEIGHT, SPACING, origin=(-0.5 * WIDTH, 0.0))


def block_mesh() -> TissueMesh:
    return mesh_rectangle(BLOCK_W, BLOCK_H, SPACING, origin=(-0.5 * BLOCK_W, HEIGHT + BLOCK_GAP))


def press_depth() -> float:
    return HEIGHT / 3


def press_y(t: float) -> float:
    """The capsule's commanded height at time t: from 1 mm above the top a third deep at PRESS_SPEED, then held."""
    y0 = HEIGHT + CAPSULE_RADIUS + 0.001
    travel = 0.001 + press_depth()
    return y0 - travel * min(1.0, t / (travel / PRESS_SPEED))


def press_time(quick: bool) -> float:
    return (0.001 + press_depth()) / PRESS_SPEED + (0.1 if quick else PRESS_HOLD)


# ----------------------------------------------------------------------------- the measures


def inside_capsule(x: np.ndarray, cx: float, cy: float) -> tuple[int, float]:
    """Vertices inside the flat capsule centred at (cx, cy) and the deepest one's depth [m] (0 when none)."""
    h = 0.5 * CAPSULE_LENGTH
    px = np.clip(x[:, 0] - cx, -h, h)
    d = np.hypot(x[:, 0] - cx - px, x[:, 1] - cy)
    inside = d < CAPSULE_RADIUS
    return int(inside.sum()), float((CAPSULE_RADIUS - d[inside]).max()) if inside.any() else 0.0


def _boundary_edges(tris: np.ndarray) -> np.ndarray:
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq[counts == 1]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point p (P, 2) to the nearest of the segments a-b (E, 2): (P,)."""
    ab = b - a
    t = np.clip(((p[:, None, :] - a[None]) * ab[None]).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300)[None], 0, 1)
    q = a[None] + t[..., None] * ab[None]
    return np.sqrt(((p[:, None, :] - q) ** 2).sum(-1)).min(axis=1)


def _inside_triangles(p: np.ndarray, x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Which points p (P, 2) lie strictly inside a triangle of (x, tris): (P,) bool."""
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]

    def cross(o, u, v):
        return (u[None, :, 0] - o[None, :, 0]) * (v[:, None, 1] - o[None, :, 1]) - \
            (u[None, :, 1] - o[None, :, 1]) * (v[:, None, 0] - o[None, :, 0])

    s1, s2, s3 = cross(a, b, p), cross(b, c, p), cross(c, a, p)
    inside = ((s1 > 0) & (s2 > 0) & (s3 > 0)) | ((s1 < 0) & (s2 < 0) & (s3 < 0))
    return inside.any(axis=1)


def overlap(x: np.ndarray, tris: np.ndarray, body: np.ndarray) -> tuple[int, float, float]:
    """Two bodies (0, 1): (vertices of either inside a triangle of the other, the deepest's distance to the other's
    boundary [m], the smallest distance of a vertex outside the other body to its boundary [m])."""
    n_in, depth, gap = 0, 0.0, math.inf
    tri_body = body[tris[:, 0]]
    for me, other in ((0, 1), (1, 0)):
        p = x[body == me]
        t = tris[tri_body == other]
        edges = _boundary_edges(t)
        d = _segment_distance(p, x[edges[:, 0]], x[edges[:, 1]])
        inside = _inside_triangles(p, x, t)
        n_in += int(inside.sum())
        if inside.any():
            depth = max(depth, float(d[inside].max()))
        if (~inside).any():
            gap = min(gap, float(d[~inside].min()))
    return n_in, depth, gap


# ----------------------------------------------------------------------------- ours


def _ours_config(name: str, tool: bool, dt: float = OURS_DT):
    from ..core.config import resolve_config  # noqa: PLC0415

    values = {"material": "neo_hookean", "young_modulus": YOUNG, "poisson_ratio": NU, "thickness": THICKNESS,
              "density": DENSITY, "gravity": -GRAVITY, "pin_y_bottom": 0.0005, "boundary_y_top": math.nan,
              "boundary_y_bottom": math.nan, "dt": dt, "damping": DAMPING, **OURS[name]}
    if tool:
        values.update(tool_shape="capsule", tool_length=CAPSULE_LENGTH, tool_radius=CAPSULE_RADIUS)
    return resolve_config(values, source="bench peers --fem contact")


def press_ours(name: str, quick: bool) -> dict[str, Any]:
    from ..core.contact.tool import ToolPose  # noqa: PLC0415
    from ..core.sim.simulation import Simulation  # noqa: PLC0415

    sim = Simulation.from_config(_ours_config(name, True), mesh=strip_mesh())
    dt = sim.params.dt
    n = int(round(press_time(quick) / dt))
    sim.place_tool(ToolPose(0.0, press_y(0.0), 0.0))
    fy, its = [], []
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        r = sim.step(ToolPose(0.0, press_y(k * dt), 0.0))
        fy.append(float(r.reaction_force[1]))
        its.append(r.solve_iterations)
    wall = time.perf_counter() - t0
    at = r.tool_applied
    n_in, depth = inside_capsule(sim.state.particle_q, at.x, at.y)
    tail = max(1, n // 10)
    return {"scene": "press", "peer": name, "dt": dt, "steps": n, "inside": n_in, "depth_m": depth,
            "force_N": float(np.mean(np.abs(fy[-tail:]))), "lag_m": float(r.tool_lag), "wall_s": wall,
            "ms_per_step": 1e3 * wall / n, "iterations_median": float(np.median(its))}


def drop_ours(name: str, quick: bool) -> dict[str, Any]:
    from ..core.mesh.types import combine_meshes  # noqa: PLC0415
    from ..core.sim.simulation import Simulation  # noqa: PLC0415

    mesh = combine_meshes([strip_mesh(), block_mesh()], [["strip"], ["block"]])
    sim = Simulation.from_config(_ours_config(name, False), mesh=mesh)
    body = np.asarray(sim.model.particle_body)
    weight = float(np.asarray(sim.model.particle_mass)[body == 1].sum()) * GRAVITY
    tris = np.asarray(sim.model.tri_indices)
    dt = sim.params.dt
    n = int(round((0.3 if quick else DROP_TIME) / dt))
    tail = max(1, n // 10)
    forces, its, worst_in, worst_depth, wall = [], [], 0, 0.0, 0.0
    for k in range(n):
        t0 = time.perf_counter()
        r = sim.step()
        wall += time.perf_counter() - t0
        its.append(r.solve_iterations)
        if r.contact_force is not None:
            forces.append(float(r.contact_force[1][1]))
        n_in, depth, _ = overlap(sim.state.particle_q, tris, body)
        worst_in, worst_depth = max(worst_in, n_in), max(worst_depth, depth)
    n_in, depth, gap = overlap(sim.state.particle_q, tris, body)
    return {"scene": "drop", "peer": name, "dt": dt, "steps": n, "inside": n_in, "depth_m": depth,
            "inside_max": worst_in, "depth_max_m": worst_depth, "gap_m": gap,
            "force_over_weight": float(np.mean(forces[-tail:])) / weight if forces else math.nan,
            "wall_s": wall, "ms_per_step": 1e3 * wall / n, "iterations_median": float(np.median(its))}


# ----------------------------------------------------------------------------- MuJoCo


def mujoco_has_ipc() -> bool:
    import mujoco  # noqa: PLC0415

    return hasattr(mujoco.mjtEnableBit, "mjENBL_IPC")


def _flex(name: str, mesh: TissueMesh, mass: np.ndarray, pinned: np.ndarray) -> str:
    points = " ".join(f"{x:.9g} {y:.9g} 0" for x, y in mesh.vertices)
    elements = " ".join(str(int(i)) for i in mesh.triangles.ravel())
    pin = f'<pin id="{" ".join(map(str, pinned))}"/>' if len(pinned) else ""
    return f"""<flexcomp name="{name}" type="direct" dim="2" dof="2d" point="{points}" element="{elements}"
              mass="{mass.sum()}" radius="{MUJOCO_RADIUS}">
      <elasticity young="{YOUNG}" poisson="{NU}" thickness="{THICKNESS}" elastic2d="stretch"/>
      <contact contype="1" conaffinity="1" selfcollide="none" condim="1"/>
      {pin}
    </flexcomp>"""


def _mujoco(meshes: Sequence[TissueMesh], ipc: bool, tool_y: float | None):
    """The model (flexes in order, a capsule on a mocap body when ``tool_y``), lumped masses, damping."""
    import mujoco  # noqa: PLC0415

    from ..core.physics.material import lumped_mass  # noqa: PLC0415

    masses = [lumped_mass(m.vertices, m.triangles, DENSITY, THICKNESS) for m in meshes]
    flexes = "".join(_flex(f"body{k}", m, masses[k], np.flatnonzero(m.vertices[:, 1] < 0.0005) if k == 0 else [])
                     for k, m in enumerate(meshes))
    tool = "" if tool_y is None else (
        f'<body name="tool" mocap="true" pos="0 {tool_y} 0"><geom type="capsule" '
        f'fromto="{-0.5 * CAPSULE_LENGTH} 0 0 {0.5 * CAPSULE_LENGTH} 0 0" size="{CAPSULE_RADIUS}" condim="1"/></body>')
    flag = '<flag ipc="enable"/>' if ipc else ""
    xml = f"""<mujoco>
  <option timestep="{MUJOCO_DT}" gravity="0 {-GRAVITY} 0" integrator="discrete">{flag}</option>
  <size memory="1G"/>
  <worldbody>{tool}{flexes}</worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    mass = np.concatenate(masses)
    body = model.flex_vertbodyid[:model.nflexvert]
    free = body > 0
    model.body_mass[body[free]] = mass[free]
    for j in range(model.njnt):
        model.dof_damping[model.jnt_dofadr[j]] = DAMPING * model.body_mass[model.jnt_bodyid[j]]
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)
    # the y direction of each dof (slide joints along x and y) and the flex vertex (-1: none) it moves
    dof_y = model.jnt_axis[model.dof_jntid][:, 1]
    vert_of_body = np.full(model.nbody, -1)
    vert_of_body[body[free]] = np.flatnonzero(free)
    dof_vert = vert_of_body[model.dof_bodyid]
    return model, data, dof_y, dof_vert


def _bad(data) -> bool:
    import mujoco  # noqa: PLC0415

    return data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0


def press_mujoco(ipc: bool, quick: bool) -> dict[str, Any]:
    import mujoco  # noqa: PLC0415

    model, data, dof_y, dof_vert = _mujoco([strip_mesh()], ipc, press_y(0.0))
    n = int(round(press_time(quick) / MUJOCO_DT))
    tail = max(1, n // 10)
    fy = []
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        data.mocap_pos[0, 1] = press_y(k * MUJOCO_DT)
        mujoco.mj_step(model, data)
        # the tissue's contact force (its only constraint) is minus the reaction on the tool
        fy.append(-float((data.qfrc_constraint * dof_y).sum()))
    wall = time.perf_counter() - t0
    n_in, depth = inside_capsule(data.flexvert_xpos[:, :2], 0.0, float(data.mocap_pos[0, 1]))
    return {"scene": "press", "peer": "mujoco_ipc" if ipc else "mujoco", "dt": MUJOCO_DT, "steps": n,
            "inside": n_in, "depth_m": depth, "force_N": float(np.mean(np.abs(fy[-tail:]))), "lag_m": 0.0,
            "wall_s": wall, "ms_per_step": 1e3 * wall / n, "iterations_median": math.nan, "diverged": _bad(data)}


def drop_mujoco(ipc: bool, quick: bool) -> dict[str, Any]:
    import mujoco  # noqa: PLC0415

    strip, block = strip_mesh(), block_mesh()
    model, data, dof_y, dof_vert = _mujoco([strip, block], ipc, None)
    ns = len(strip.vertices)
    body = np.r_[np.zeros(ns, int), np.ones(len(block.vertices), int)]
    tris = np.r_[strip.triangles, block.triangles + ns]
    block_dof = dof_vert >= ns
    from ..core.physics.material import lumped_mass  # noqa: PLC0415

    weight = float(lumped_mass(block.vertices, block.triangles, DENSITY, THICKNESS).sum()) * GRAVITY
    n = int(round((0.3 if quick else DROP_TIME) / MUJOCO_DT))
    tail = max(1, n // 10)
    every = max(1, int(round(OURS_DT / MUJOCO_DT)))  # the overlap checked as often in simulated time as ours
    forces, worst_in, worst_depth, wall = [], 0, 0.0, 0.0
    for k in range(1, n + 1):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        wall += time.perf_counter() - t0
        forces.append(float((data.qfrc_constraint * dof_y)[block_dof].sum()))
        if k % every == 0:
            n_in, depth, _ = overlap(data.flexvert_xpos[:, :2], tris, body)
            worst_in, worst_depth = max(worst_in, n_in), max(worst_depth, depth)
    n_in, depth, gap = overlap(data.flexvert_xpos[:, :2], tris, body)
    return {"scene": "drop", "peer": "mujoco_ipc" if ipc else "mujoco", "dt": MUJOCO_DT, "steps": n,
            "inside": n_in, "depth_m": depth, "inside_max": max(worst_in, n_in), "depth_max_m": max(worst_depth, depth),
            "gap_m": gap, "force_over_weight": float(np.mean(forces[-tail:])) / weight, "wall_s": wall,
            "ms_per_step": 1e3 * wall / n, "iterations_median": math.nan, "diverged": _bad(data)}


# ----------------------------------------------------------------------------- the comparison

COLUMNS = ["scene", "peer", "dt", "steps", "inside", "depth_m", "inside_max", "depth_max_m", "gap_m", "force_N",
           "force_over_weight", "lag_m", "iterations_median", "wall_s", "ms_per_step", "diverged"]


def compare(quick: bool, with_mujoco: bool, progress=None) -> list[dict[str, Any]]:
    """Every scene and peer, one after the other (ours first, MuJoCo's modes after): rows of :data:`COLUMNS`."""
    runs = [(press_ours, name) for name in OURS] + [(drop_ours, name) for name in OURS]
    if with_mujoco:
        modes = [False] + ([True] if mujoco_has_ipc() else [])
        runs += [(press_mujoco, ipc) for ipc in modes] + [(drop_mujoco, ipc) for ipc in modes]
    rows = []
    for fn, arg in runs:
        row = fn(arg, quick)
        rows.append({c: row.get(c, math.nan if c not in ("diverged",) else False) for c in COLUMNS})
        if progress is not None:
            progress(row)
    return rows


def plot(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Penetration, force and wall time per peer, press and drop side by side."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    press = [r for r in rows if r["scene"] == "press"]
    drop = [r for r in rows if r["scene"] == "drop"]
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.6))
    panels = [(axes[0], press, "depth_m", 1e3, "press: deepest vertex inside the tool [mm]"),
              (axes[1], drop, "depth_max_m", 1e3, "drop: deepest vertex inside the other body [mm]"),
              (axes[2], drop, "force_over_weight", 1.0, "drop: block's contact force / weight"),
              (axes[3], rows, "wall_s", 1.0, "wall time of the run [s]")]
    for ax, sel, key, scale, title in panels:
        labels = [f"{r['peer']}, {r['scene']}" if sel is rows else r["peer"] for r in sel]
        values = [scale * r[key] if np.isfinite(r[key]) else 0.0 for r in sel]
        ax.bar(range(len(sel)), values, color=["C0" if r["peer"].startswith("ours") else "C1" for r in sel])
        ax.set_xticks(range(len(sel)), labels, fontsize=6, rotation=60 if sel is rows else 0,
                      ha="right" if sel is rows else "center")
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=7)
        if key == "force_over_weight":
            ax.axhline(1.0, color="k", lw=0.8)
        if key == "wall_s":
            ax.set_yscale("log")
    fig.suptitle("Contact scenes (E 50 kPa strip, 2.5 mm mesh): ours at dt 10 ms, MuJoCo at 1 ms", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_contact(out: Path, quick: bool, have_mujoco: bool) -> list[dict[str, Any]]:
    """The comparison printed, written (peers_contact.csv) and charted (peers_contact.png) into ``out``."""
    from .accuracy import format_table  # noqa: PLC0415
    from .refinement import write_csv  # noqa: PLC0415

    def line(r: dict[str, Any]) -> None:
        print(f"  {r['scene']} {r['peer']}: {r['inside']} inside, {1e3 * r['depth_m']:.3g} mm deep, "
              f"{r['wall_s']:.2f} s", flush=True)

    if have_mujoco:
        import mujoco  # noqa: PLC0415

        print(f"contact scenes: MuJoCo {mujoco.__version__}, IPC mode {'available' if mujoco_has_ipc() else 'absent'}")
    else:
        print("contact scenes: MuJoCo not installed (pip install '.[peers]'): ours only")
    rows = compare(quick, have_mujoco, progress=line)
    write_csv(out / "peers_contact.csv", rows)
    plot(out / "peers_contact.png", rows)
    shown = [{**r, "depth_m": f"{1e3 * r['depth_m']:.3g} mm",
              "depth_max_m": f"{1e3 * r['depth_max_m']:.3g} mm" if np.isfinite(r["depth_max_m"]) else "-",
              "gap_m": f"{1e3 * r['gap_m']:.3g} mm" if np.isfinite(r["gap_m"]) else "-",
              "lag_m": f"{1e3 * r['lag_m']:.3g} mm" if np.isfinite(r["lag_m"]) else "-",
              "force_over_weight": f"{r['force_over_weight']:.5f}" if np.isfinite(r["force_over_weight"]) else "-"}
             for r in rows]
    print("press (capsule r 2.5 mm a third deep into the E 50 kPa strip at 1 cm/s, held) and drop (a 4 x 1 cm block "
          "released 1 mm above it): vertices inside the tool / the other body at the end (and at most), force, "
          "wall time:")
    print(format_table(shown, [c for c in COLUMNS if c != "steps"]))
    print(f"wrote {out / 'peers_contact.csv'} and {out / 'peers_contact.png'}")
    return rows
