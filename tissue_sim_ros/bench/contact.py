"""Contact cost: python-fcl queries per step, culled versus full per-step BVH rebuild.

python-fcl 0.7 cannot refit a BVHModel in place (no beginUpdateModel /
updateVertex / endUpdateModel in its bindings), so the tissue's BVH must be
rebuilt each step. This benchmark measures what that costs:

* ``full``: every body's whole triangle mesh rebuilt as a BVHModel each step
  (``ContactModel(cull=False)``);
* ``culled``: only the triangles that can hold the nearest point go into the
  step's BVH (the default);

on two scenes: the paper-sized default scene (config/tissue.png, two bodies,
experiment a's trajectory: the authors' 0.8 m box at 0.001 m per step) and a
1 m x 0.5 m strip of ~5,000 triangles with the same tool descending at 30
degrees. Each step, the simulation advances with the culled model; both
models' ``detect`` are timed on the same state (and their d* compared). Rows
report medians over the steps with the tool within alpha of the tissue (d*
computed), and the whole ``Simulation.step`` median for scale. Writes
``contact.csv`` and ``contact.png``.

**Force smoothness** (:func:`smoothness`): the default step for ``material: neo_hookean`` (``method: ipc``,
``contact_model: barrier``) beside the former default (``quasi_newton`` with ``projection`` contact, the
library's other defaults) on a 6 x 2 cm strip (2.5 mm mesh, bottom row pinned, nu 0.45, 5 mm thick, 1000
kg/m^3, gravity, damping 10 1/s) under a horizontal capsule (segment 2 cm, radius 2.5 mm), E 4 kPa and 50 kPa,
dt 10 ms:

* ``hold``: the capsule, centred, from 1 mm above the top pressed a third of the height deep at 1 cm/s, then held
  still :data:`HOLD_STEPS` steps. Over the held steps: the step-to-step change of the normal reaction |Fy|
  relative to its mean (median, max), the lateral over the normal force |Fx|/|Fy| (median, max), the solve's
  iterations (median, max), the steps that end with an inverted triangle, the deepest particle inside the tool;
* ``drag``: pressed 3 mm deep 1 cm left of the centre at 1 cm/s, then dragged 2 cm to the right at 1 cm/s, with
  tool-tissue friction 0 and 0.3 (the barrier's lagged IPC friction; projection contact has none, so the former
  default is dragged frictionless only). Over the drag after its first 5 mm: Fx/Fy (median), the step-to-step
  change of |F| relative to its mean (median, max), iterations, inverted steps, the tool's lag at the end.

Writes ``contact_smoothness.csv`` (one row per case), ``contact_smoothness_steps.csv`` (the reaction at every
step) and ``contact_smoothness.png`` (the reaction over the steps, both methods).

Run: ``tissue-sim bench contact [--out DIR] [--steps N] [--quick] [--only detection|smoothness]``.
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import resolve_config
from ..core.contact.collision import ContactModel
from ..core.contact.tool import StraightInsertion, ToolPose
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.sim.simulation import Simulation


def _scenes(kind: str, quick: bool = False) -> list[tuple[str, Simulation, StraightInsertion]]:
    from ..core.sim.scene import build_simulation  # noqa: PLC0415
    from ..core.timing.trajectories import experiment_a  # noqa: PLC0415

    sim = build_simulation({"contact_model": kind})
    scenes = [("paper scene", sim, experiment_a(sim.tool, sim.params.dt))]
    if quick:
        return scenes
    # ~5,000 triangles: 71 x 35 cells of two triangles
    strip = mesh_rectangle(1.0, 0.5, 1.0 / 71)
    # the shipped parameters and tool; the strip pinned along its bottom row, no top line
    cfg = resolve_config({"contact_model": kind, "boundary_y_bottom": 0.001, "boundary_y_top": math.nan},
                         source="bench contact strip")
    big = Simulation.from_config(cfg, mesh=strip)
    traj = StraightInsertion.from_angle(big.tool, target=(0.6, 0.42), angle=math.radians(-30), distance=0.2,
                                        speed=0.001, dt=big.params.dt)
    scenes.append((f"strip {strip.triangles.shape[0]} tris", big, traj))
    return scenes


def measure(kind: str, steps: int, progress=None, quick: bool = False) -> list[dict[str, Any]]:
    """Rows (one per scene and BVH mode) for one contact model."""
    rows = []
    for name, sim, traj in _scenes(kind, quick):
        full = ContactModel(sim.model, sim.tool, cull=False)
        culled = sim.contact
        t_full, t_cull, tris_full, tris_cull, totals, worst = [], [], [], [], [], 0.0
        prev = None
        for k, (pose, twist) in enumerate(traj.steps(sim.params.dt)):
            if k >= steps:
                break
            state = sim.state
            pose0 = prev or pose
            t0 = time.perf_counter()
            c_cull = culled.detect(state, pose0, pose, twist, sim.params.dt)
            t1 = time.perf_counter()
            c_full = full.detect(state, pose0, pose, twist, sim.params.dt)
            t2 = time.perf_counter()
            report = sim.step(pose, twist)
            prev = pose
            if progress is not None:
                progress.update(1)
            if not np.isfinite(c_cull.d_star).any():
                continue
            # where the culled model computed d*, the full BVH must agree
            ok = np.isfinite(c_cull.d_star)
            worst = max(worst, float(np.abs(c_cull.d_star[ok] - c_full.d_star[ok]).max()))
            t_cull.append(t1 - t0)
            t_full.append(t2 - t1)
            tris_cull.append(culled.last_bvh_triangles)
            tris_full.append(full.last_bvh_triangles)
            totals.append(report.timings["total"])
        if not t_cull:
            continue
        step_ms = 1e3 * float(np.median(totals))
        for mode, ts, tris in (("culled", t_cull, tris_cull), ("full", t_full, tris_full)):
            ms = 1e3 * float(np.median(ts))
            rows.append(dict(scene=name, contact_model=kind, bvh=mode, particles=sim.model.n_particles,
                             triangles=sim.model.n_triangles, steps_near=len(ts), detect_ms=ms,
                             detect_p90_ms=1e3 * float(np.percentile(ts, 90)),
                             bvh_triangles=float(np.median(tris)), step_ms=step_ms,
                             share=ms / step_ms, max_dstar_diff=worst))
    return rows


# ----------------------------------------------------------------------------- force smoothness

#: method name -> its parameters (ipc: what ``material: neo_hookean`` resolves to with no solver keys)
SMOOTH_METHODS = {"ipc": {"method": "ipc", "contact_model": "barrier"},
                  "quasi_newton": {"method": "quasi_newton", "contact_model": "projection"}}
SMOOTH_MODULI = (4e3, 50e3)
SMOOTH_DT = 0.01
SMOOTH_SPEED = 0.01
STRIP_W, STRIP_H, STRIP_SPACING = 0.06, 0.02, 0.0025
CAPSULE_LENGTH, CAPSULE_RADIUS = 0.02, 0.0025
HOLD_STEPS = 100
DRAG_DEPTH, DRAG_DISTANCE = 0.003, 0.02
DRAG_SKIP = 0.005
FRICTIONS = (0.0, 0.3)


def smooth_config(method: str, young: float, friction: float = 0.0, dt: float = SMOOTH_DT):
    """The strip's configuration for one method (the friction only where the contact has it: barrier)."""
    extra = {"friction": friction} if SMOOTH_METHODS[method]["contact_model"] == "barrier" else {}
    return resolve_config({"material": "neo_hookean", "young_modulus": young, "poisson_ratio": 0.45,
                           "thickness": 0.005, "density": 1000.0, "tool_shape": "capsule",
                           "tool_length": CAPSULE_LENGTH, "tool_radius": CAPSULE_RADIUS, "gravity": -9.8,
                           "pin_y_bottom": 0.0005, "boundary_y_top": math.nan, "boundary_y_bottom": math.nan,
                           "dt": dt, "damping": 10.0, **SMOOTH_METHODS[method], **extra},
                          source="bench contact smoothness")


def smooth_poses(case: str, dt: float = SMOOTH_DT, speed: float = SMOOTH_SPEED, hold: int = HOLD_STEPS,
                 drag: float = DRAG_DISTANCE) -> tuple[list[ToolPose], int, int]:
    """(poses, first measured step, last measured step + 1): ``hold``: from 1 mm above the centre a third deep,
    then ``hold`` steps still; ``drag``: 3 mm deep 1 cm left of the centre, then ``drag`` m to the right.
    The capsule lies flat (yaw 0): its lowest point is its radius below the pose."""
    step = speed * dt
    y0 = STRIP_H + CAPSULE_RADIUS + 0.001
    depth = STRIP_H / 3 if case == "hold" else DRAG_DEPTH
    x0 = 0.0 if case == "hold" else -0.5 * drag
    n_press = max(1, int(math.ceil((0.001 + depth) / step - 1e-9)))
    out = [ToolPose(x0, y0 - (0.001 + depth) * k / n_press, 0.0) for k in range(1, n_press + 1)]
    if case == "hold":
        return out + [out[-1]] * hold, n_press, n_press + hold
    n_drag = max(1, int(math.ceil(drag / step - 1e-9)))
    out += [ToolPose(x0 + drag * k / n_drag, out[-1].y, 0.0) for k in range(1, n_drag + 1)]
    skip = min(n_drag - 1, int(round(DRAG_SKIP / step)))
    return out, n_press + skip, n_press + n_drag


def _rel_changes(values: np.ndarray) -> np.ndarray:
    """|v[k+1] - v[k]| over the mean |v| (empty for fewer than two values)."""
    scale = float(np.mean(np.abs(values))) if values.size else 0.0
    if values.size < 2 or scale == 0.0:
        return np.zeros(0)
    return np.abs(np.diff(values)) / scale


def smooth_case(method: str, young: float, case: str, friction: float = 0.0, *, hold: int = HOLD_STEPS,
                drag: float = DRAG_DISTANCE, progress=None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """One case: its row (the measures over the measured steps) and the reaction at every step."""
    sim = Simulation.from_config(smooth_config(method, young, friction),
                                 mesh=mesh_rectangle(STRIP_W, STRIP_H, STRIP_SPACING, origin=(-0.5 * STRIP_W, 0.0)))
    poses, first, last = smooth_poses(case, hold=hold, drag=drag)
    sim.place_tool(ToolPose(poses[0].x, STRIP_H + CAPSULE_RADIUS + 0.001, 0.0))
    steps = []
    for k, pose in enumerate(poses):
        r = sim.step(pose)
        steps.append({"method": method, "young_modulus": young, "case": case, "friction": friction, "step": k + 1,
                      "measured": first <= k < last, "fx": float(r.reaction_force[0]),
                      "fy": float(r.reaction_force[1]), "iterations": int(r.solve_iterations),
                      "n_inverted": int(r.n_inverted), "penetration_m": float(r.penetration_depth),
                      "tool_lag_m": float(r.tool_lag), "solve_ms": 1e3 * r.timings["solve"],
                      "converged": bool(r.solve_converged)})
        if progress is not None:
            progress.update(1)
    sel = steps[first:last]
    fx = np.array([s["fx"] for s in sel])
    fy = np.array([s["fy"] for s in sel])
    its = np.array([s["iterations"] for s in sel])
    normal = _rel_changes(np.abs(fy))
    total = _rel_changes(np.hypot(fx, fy))
    lateral = np.abs(fx) / np.maximum(np.abs(fy), 1e-300)
    row = {"method": method, "young_modulus": young, "case": case, "friction": friction, "steps": len(sel),
           "fy_mean_N": float(np.mean(fy)), "fx_mean_N": float(np.mean(fx)),
           "dfn_median": float(np.median(normal)) if normal.size else math.nan,
           "dfn_max": float(normal.max()) if normal.size else math.nan,
           "df_median": float(np.median(total)) if total.size else math.nan,
           "df_max": float(total.max()) if total.size else math.nan,
           "lateral_median": float(np.median(lateral)), "lateral_max": float(lateral.max()),
           "fx_over_fy": float(np.median(fx) / np.median(fy)) if np.median(fy) else math.nan,
           "its_median": float(np.median(its)), "its_max": int(its.max()),
           "inverted_steps": int(sum(s["n_inverted"] > 0 for s in sel)),
           "unconverged_steps": int(sum(not s["converged"] for s in sel)),
           "penetration_max_m": max(s["penetration_m"] for s in steps),
           "lag_end_m": steps[-1]["tool_lag_m"],
           "solve_ms_median": float(np.median([s["solve_ms"] for s in sel]))}
    return row, steps


def smoothness(quick: bool = False, progress=None) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Every case of :func:`smooth_case` (``quick``: E 50 kPa, 10 held steps, a 1 cm drag)."""
    hold, drag = (10, 0.01) if quick else (HOLD_STEPS, DRAG_DISTANCE)
    moduli = (50e3,) if quick else SMOOTH_MODULI
    rows, steps = [], []
    for young in moduli:
        for method in SMOOTH_METHODS:
            cases = [("hold", 0.0)] + [("drag", mu) for mu in FRICTIONS
                                       if mu == 0.0 or SMOOTH_METHODS[method]["contact_model"] == "barrier"]
            for case, mu in cases:
                row, series = smooth_case(method, young, case, mu, hold=hold, drag=drag, progress=progress)
                rows.append(row)
                steps += series
    return rows, steps


def smoothness_steps(quick: bool) -> int:
    """Steps :func:`smoothness` takes (for a progress bar)."""
    hold, drag = (10, 0.01) if quick else (HOLD_STEPS, DRAG_DISTANCE)
    per = len(smooth_poses("hold", hold=hold)[0]) + len(smooth_poses("drag", drag=drag)[0])
    n_moduli = 1 if quick else len(SMOOTH_MODULI)
    return n_moduli * (per + len(smooth_poses("drag", drag=drag)[0]) + per)


def plot_smoothness(path: Path, steps: list[dict[str, Any]]) -> None:
    """The reaction over the steps: a row per E, a column per case; ipc solid, quasi_newton dashed."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    moduli = sorted({s["young_modulus"] for s in steps})
    cases = [("hold", 0.0), ("drag", 0.0), ("drag", 0.3)]
    fig, axes = plt.subplots(len(moduli), len(cases), figsize=(4.2 * len(cases), 3.0 * len(moduli) + 0.4),
                             squeeze=False)
    styles = {"ipc": "-", "quasi_newton": "--"}
    for i, young in enumerate(moduli):
        for j, (case, mu) in enumerate(cases):
            ax = axes[i][j]
            for method in SMOOTH_METHODS:
                sel = [s for s in steps if s["method"] == method and s["young_modulus"] == young
                       and s["case"] == case and s["friction"] == mu]
                if not sel:
                    continue
                k = [s["step"] for s in sel]
                ax.plot(k, [s["fy"] for s in sel], styles[method], color="C0", lw=1, label=f"{method} Fy")
                ax.plot(k, [s["fx"] for s in sel], styles[method], color="C3", lw=1, label=f"{method} Fx")
                measured = [s["step"] for s in sel if s["measured"]]
                if measured and method == "ipc":
                    ax.axvspan(measured[0], measured[-1], color="0.92", zorder=0)
            what = "pressed a third deep, held" if case == "hold" else f"3 mm deep, dragged at 1 cm/s, friction {mu:g}"
            ax.set_title(f"E {young / 1e3:g} kPa: {what}", fontsize=8)
            ax.set_xlabel("step (dt 10 ms)", fontsize=7)
            ax.tick_params(labelsize=7)
            if j == 0:
                ax.set_ylabel("reaction on the tool [N]", fontsize=7)
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=6)
    fig.suptitle("Reaction over the steps: ipc (barrier, solid) and the former default (quasi_newton + projection, "
                 "dashed); shaded: the steps measured", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=120)
    plt.close(fig)


SMOOTH_COLUMNS = ["method", "young_modulus", "case", "friction", "fy_mean_N", "dfn_median", "dfn_max", "df_median",
                  "df_max", "lateral_median", "lateral_max", "fx_over_fy", "its_median", "its_max", "inverted_steps",
                  "unconverged_steps", "penetration_max_m", "lag_end_m", "solve_ms_median"]


def _write(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def run_smoothness(out: Path, quick: bool) -> list[dict[str, Any]]:
    """:func:`smoothness` printed, written (CSV, per-step CSV) and charted into ``out``."""
    from tqdm import tqdm  # noqa: PLC0415

    from .accuracy import format_table  # noqa: PLC0415

    with tqdm(total=smoothness_steps(quick), desc="contact force smoothness", unit="step", dynamic_ncols=True) as bar:
        rows, steps = smoothness(quick, bar)
    shown = [{**r, **{c: f"{100 * r[c]:.3g}%" for c in ("dfn_median", "dfn_max", "df_median", "df_max",
                                                           "lateral_median", "lateral_max")},
              "penetration_max_m": f"{1e3 * r['penetration_max_m']:.3g} mm", "lag_end_m": f"{1e3 * r['lag_end_m']:.3g} mm"}
             for r in rows]
    print("force smoothness (6 x 2 cm strip, 2.5 mm mesh, capsule r 2.5 mm, dt 10 ms): held = a third deep, 100 "
          "steps still (dfn: step-to-step change of |Fy| / its mean; lateral: |Fx|/|Fy|); drag = 3 mm deep, 2 cm at "
          "1 cm/s (df: of |F|; the first 5 mm left out)")
    print(format_table(shown, SMOOTH_COLUMNS))
    _write(out / "contact_smoothness.csv", rows)
    _write(out / "contact_smoothness_steps.csv", steps)
    plot_smoothness(out / "contact_smoothness.png", steps)
    print(f"wrote {out / 'contact_smoothness.csv'}, {out / 'contact_smoothness_steps.csv'} and "
          f"{out / 'contact_smoothness.png'}")
    return rows




PARTS = ("detection", "smoothness")


def run(out: str | Path, *, steps: int | None = None, quick: bool = False, only: str | None = None) -> int:
    """Time both BVH modes on both scenes and contact models (``detection``: contact.csv/png) and measure the force
    smoothness of the material's default step against the former default (``smoothness``:
    contact_smoothness.csv/png); print both and write them into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    steps : int, optional
        Steps of each detection trajectory (default 300; ``quick`` 160).
    quick : bool
        The paper scene only; smoothness at E 50 kPa with 10 held steps and a 1 cm drag (smoke test).
    only : str, optional
        ``detection`` or ``smoothness``: that part alone (default both).

    Returns
    -------
    int
        0, or 1 when no step brought the tool within alpha of the tissue.
    """
    if only is not None and only not in PARTS:
        raise InputError(f"--only={only!r}: expected one of {', '.join(PARTS)}")
    steps = steps if steps is not None else (160 if quick else 300)
    if steps < 1:
        raise InputError(f"--steps={steps}: expected at least 1 step")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    code = 0
    if only in (None, "detection"):
        code = run_detection(out, steps, quick)
    if only in (None, "smoothness"):
        run_smoothness(out, quick)
    return code


def run_detection(out: Path, steps: int, quick: bool) -> int:
    """The detection cost: culled vs full BVH on both scenes and contact models; contact.csv/png."""
    from tqdm import tqdm  # noqa: PLC0415

    rows: list[dict[str, Any]] = []
    with tqdm(total=(2 if quick else 4) * steps, desc="contact bench") as bar:
        for kind in ("paper", "projection"):
            rows += measure(kind, steps, bar, quick)
    if not rows:
        print(f"no step brought the tool within alpha of the tissue in {steps} steps: nothing to report")
        return 1
    header = f"{'scene':<20} {'model':<10} {'bvh':<6} {'tris':>5} {'near':>5} {'bvh tris':>8} " \
             f"{'detect ms':>9} {'p90 ms':>7} {'step ms':>8} {'share':>6} {'|dd*| max':>9}"
    print(header)
    for r in rows:
        print(f"{r['scene']:<20} {r['contact_model']:<10} {r['bvh']:<6} {r['triangles']:>5} {r['steps_near']:>5} "
              f"{r['bvh_triangles']:>8.0f} {r['detect_ms']:>9.3f} {r['detect_p90_ms']:>7.3f} {r['step_ms']:>8.3f} "
              f"{r['share']:>6.1%} {r['max_dstar_diff']:>9.1e}")
    with open(out / "contact.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(9, 4))
    labels = [f"{r['scene']}\n{r['contact_model']}, {r['bvh']}" for r in rows]
    ax.bar(range(len(rows)), [r["detect_ms"] for r in rows], color=["C0" if r["bvh"] == "culled" else "C3" for r in rows])
    ax.scatter(range(len(rows)), [0.25 * r["step_ms"] for r in rows], marker="_", s=400, color="k",
               label="a quarter of the whole step")
    ax.set_xticks(range(len(rows)), labels, fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("detect() per step [ms], median")
    ax.set_title("Contact detection: culled vs full per-step python-fcl BVH rebuild")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "contact.png", dpi=120)
    print(f"wrote {out / 'contact.csv'} and {out / 'contact.png'}")
    return 0
