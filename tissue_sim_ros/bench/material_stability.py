"""``tissue-sim bench stability --material``: where the material model fails, over dt, E, tool speed, mesh quality.

A real-size strip (6 cm x 2 cm, 2.5 mm spacing, bottom row pinned, density
1000 kg/m^3, nu 0.45, 5 mm thick) of ``material: neo_hookean`` under a 5 mm
capsule held upright (the real-size scene's instrument, tip down), stepped by
the default (``method: ipc`` with ``contact_model: barrier``: the incremental
potential with contact barriers, a CCD- and inversion-capped line search, the
tool held to its command by a stiff spring) beside the former default
(``quasi_newton`` with ``projection`` contact; ``xpbd`` 10 x 10 with projection
on request, :data:`EXTRA_SCHEMES`). Two motions:

* ``press``: from 2 mm above the surface down at the tool speed until the tip is 1/3 of the strip's height deep,
  then held for 20 steps;
* ``drag``: from 2 mm above down to 3 mm deep, then 2 cm sideways at the tool speed (with ``friction`` 0.3 for
  the barrier contact; the projection contact has no friction), then held for 20 steps.

Every move runs at the tool speed (at most :data:`MAX_STEPS` steps). The sweep:

* dt: 1, 2, 5, 10, 20 ms;
* Young's modulus: 1 kPa, 10 kPa, 100 kPa, 1 MPa (soft tissue to cartilage);
* tool speed: 0.01, 0.1, 1 m/s;
* mesh quality: regular, and with slivers (interior vertices moved at random by up to 0.4 spacing);
* scheme: ipc (the default), quasi_newton + projection (the former default).

Each run's first failure is found by :class:`~tissue_sim_ros.core.health.FailureMonitor`
(non-finite values, kinetic energy past the plausible bound, triangles staying inverted for 5 steps) and by the
step's own counters against the tool where it really is (``StepReport.tool_applied``): ``tunnelling`` when
``StepReport.n_tunnelled`` counts particle paths through the tool, ``penetrating`` when particles are still
inside the tool after a step (deeper than 0.1 mm), ``buried`` when the StepReport names the tool buried; a run
that holds but whose steps say their solve stopped short (``StepReport.solve_converged`` False, what the node
warns about and counts on ``/diagnostics``) is ``unconverged``, with the count of such steps. Each run also
reports how far the tool stopped short of its command (``StepReport.tool_lag``) at its last step and at most
(the barrier contact's tool stops where the tissue cannot make room; the projection contact's never lags),
the largest reaction on the tool [N] (a step that stops short with a pair squeezed far inside dhat reads a
barrier force far above the load: before the barrier stiffened itself, the hardest press, 1 MPa at 2 cm per step,
read up to 1e8 N where the load is 24 N),
its solve iterations (median, max) and its wall time.

Writes ``material_stability.csv`` (one row per run) and ``material_stability.png`` (a map per scheme and
motion: dt x E panels, tool speed x mesh quality cells, the end lag in mm written in the cells where the tool
stopped 0.05 mm or more short) and prints a progress line per run, the failure counts, the lag and the failures.
"""
from __future__ import annotations

import itertools
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import resolve_config
from ..core.contact.tool import ToolPose, ToolShape
from ..core.health import FailureMonitor
from ..core.sim.simulation import Simulation
from .stability import sliver_mesh

WIDTH, HEIGHT, SPACING = 0.06, 0.02, 0.0025
TOOL = ToolShape("capsule", length=0.03, radius=0.0025)
DTS = (0.001, 0.002, 0.005, 0.01, 0.02)
MODULI = (1e3, 1e4, 1e5, 1e6)
SPEEDS = (0.01, 0.1, 1.0)
QUALITIES = ("regular", "slivers")
MOTIONS = ("press", "drag")
#: scheme name -> its parameters (ipc: what ``material: neo_hookean`` resolves to with no solver keys)
SOLVERS = {"ipc": {"method": "ipc", "contact_model": "barrier"},
           "quasi_newton": {"method": "quasi_newton", "contact_model": "projection"},
           "xpbd_10x10": {"method": "xpbd", "scheme": "gauss_seidel", "substeps": 10, "iterations": 10,
                          "contact_model": "projection"}}
#: the sweep's schemes: the default and the former default
SCHEMES = ("ipc", "quasi_newton")
#: further schemes a caller may ask for (``schemes=``): the default before quasi_newton, 8x its cost per step
EXTRA_SCHEMES = ("xpbd_10x10",)
#: the drag's friction coefficient (barrier contact: tool-tissue ``friction``; projection has none)
DRAG_FRICTION = 0.3
DRAG_DEPTH = 0.003
DRAG_DISTANCE = 0.02
HOLD_STEPS = 20
OUTCOMES = ("stable", "unconverged", "nonfinite", "energy_blowup", "inverted", "tunnelling", "penetrating", "buried")
PENETRATION_TOLERANCE = 1e-4
#: at most this many steps of motion per run (the 1 ms x 0.01 m/s drag takes 2,500)
MAX_STEPS = 3000
#: a lag this large [m] is written in the map's cell
LAG_SHOWN = 5e-5


def make_mesh(quality: str):
    from ..core.mesh import mesh_rectangle  # noqa: PLC0415

    if quality == "regular":
        return mesh_rectangle(WIDTH, HEIGHT, SPACING)
    return sliver_mesh(WIDTH, HEIGHT, SPACING)


def _moves(start: ToolPose, dx: float, dy: float, step: float) -> list[ToolPose]:
    """From ``start`` (excluded) by (dx, dy) in equal steps of at most ``step`` [m]."""
    n = max(1, int(math.ceil(math.hypot(dx, dy) / step - 1e-9)))
    return [ToolPose(start.x + dx * k / n, start.y + dy * k / n, start.yaw) for k in range(1, n + 1)]


def poses(dt: float, speed: float, motion: str = "press") -> list[ToolPose]:
    """The capsule upright (yaw -90 deg: tip down), its lowest point 2 mm above the top; ``press``: down to 1/3 deep;
    ``drag``: down to :data:`DRAG_DEPTH` deep 1 cm left of the centre, then :data:`DRAG_DISTANCE` to the right;
    then held for :data:`HOLD_STEPS` steps. Each move at ``speed`` (steps of speed x dt), the whole run at most
    :data:`MAX_STEPS` steps of motion (faster where that caps it)."""
    # the capsule is a segment of TOOL.length inflated by its radius: its lowest point is half + radius below the
    # pose (the sweep before 2026-12 left out the radius and started 0.5 mm inside the tissue)
    half = 0.5 * TOOL.length + TOOL.radius
    tip0 = HEIGHT + 0.002
    if motion == "press":
        legs = [(0.0, -(0.002 + HEIGHT / 3))]
        x0 = 0.5 * WIDTH
    elif motion == "drag":
        legs = [(0.0, -(0.002 + DRAG_DEPTH)), (DRAG_DISTANCE, 0.0)]
        x0 = 0.5 * WIDTH - 0.5 * DRAG_DISTANCE
    else:
        raise ValueError(f"motion {motion!r}: expected one of {', '.join(MOTIONS)}")
    travel = sum(math.hypot(dx, dy) for dx, dy in legs)
    step = max(speed * dt, travel / MAX_STEPS)
    out = [ToolPose(x0, tip0 + half, -0.5 * math.pi)]
    for dx, dy in legs:
        out += _moves(out[-1], dx, dy, step)
    return out + [out[-1]] * HOLD_STEPS


def run_one(dt: float, young: float, speed: float, quality: str, scheme: str, mesh=None,
            motion: str = "press") -> dict[str, Any]:
    """One run: its first failure (``outcome``), when, the tool's lag, the solve's iterations and the wall time."""
    extra = {"friction": DRAG_FRICTION} if motion == "drag" and SOLVERS[scheme]["contact_model"] == "barrier" else {}
    cfg = resolve_config({"material": "neo_hookean", "young_modulus": young, "poisson_ratio": 0.45,
                          "thickness": 0.005, "density": 1000.0, "dt": dt, **SOLVERS[scheme], **extra,
                          "boundary_y_bottom": 1e-9, "boundary_y_top": math.nan, "contact_margin": 0.0,
                          "tool_shape": TOOL.kind, "tool_length": TOOL.length, "tool_radius": TOOL.radius,
                          "sleep_speed": 0.0}, source="bench stability --material")
    sim = Simulation.from_config(cfg, mesh=mesh if mesh is not None else make_mesh(quality))
    monitor = FailureMonitor(sim.model, TOOL)
    ps = poses(dt, speed, motion)
    sim.place_tool(ps[0])
    outcome, step_failed, detail = "stable", 0, ""
    max_pen = 0.0
    max_inverted = 0
    unconverged = 0
    lag, max_lag = 0.0, 0.0
    max_reaction = 0.0
    iterations: list[int] = []
    t0 = time.perf_counter()
    for k in range(1, len(ps)):
        x_prev = sim.state.particle_q.copy()
        with np.errstate(all="ignore"):
            r = sim.step(ps[k])
        iterations.append(int(r.solve_iterations))
        max_inverted = max(max_inverted, int(r.n_inverted))
        unconverged += int(not r.solve_converged)
        lag = float(r.tool_lag)
        max_reaction = max(max_reaction, float(np.hypot(*np.asarray(r.reaction_force, dtype=float)[:2])))
        max_lag = max(max_lag, lag)
        pen = float(getattr(r, "penetration_depth", 0.0)) if getattr(r, "n_penetrating", 0) else 0.0
        max_pen = max(max_pen, pen)
        moved = math.hypot(ps[k].x - ps[k - 1].x, ps[k].y - ps[k - 1].y) / dt
        # tunnelling from the step's own counter (StepReport.n_tunnelled: paths through the tool within the
        # step, against where the tool really went); the monitor's swept check, written for the metre-scale box,
        # flagged a capsule 2 mm above the tissue at step 1, so it is not used here
        failure = monitor.observe(k, x_prev, sim.state.particle_q, sim.state.particle_qd, k * dt,
                                  diverged=r.diverged, tool_speed=moved)
        if failure is not None:
            outcome, step_failed, detail = failure.kind, failure.step, failure.detail
            break
        if getattr(r, "n_tunnelled", 0):
            outcome, step_failed, detail = "tunnelling", k, f"{r.n_tunnelled} particle paths through the tool"
            break
        if getattr(r, "tool_buried", False):
            outcome, step_failed, detail = "buried", k, "StepReport.tool_buried"
            break
        if pen > PENETRATION_TOLERANCE:
            outcome, step_failed, detail = "penetrating", k, f"{r.n_penetrating} particles, {pen * 1e3:.2f} mm deep"
            break
    wall = time.perf_counter() - t0
    if outcome not in OUTCOMES:
        outcome = "energy_blowup" if "energy" in outcome else outcome
    if outcome == "stable" and unconverged:
        outcome, detail = "unconverged", f"{unconverged} of {len(ps) - 1} steps stopped short of solve_tolerance"
    its = np.asarray(iterations or [0])
    return {"motion": motion, "dt": dt, "young_modulus": young, "tool_speed": speed, "mesh_quality": quality,
            "scheme": scheme, "outcome": outcome, "failure_step": step_failed, "detail": detail,
            "steps": len(ps) - 1, "steps_run": len(iterations), "max_penetration_m": max_pen,
            "max_inverted": max_inverted, "max_kinetic_ratio": monitor.max_kinetic_ratio,
            "unconverged_steps": unconverged, "lag_end_m": lag, "lag_max_m": max_lag,
            "max_reaction_n": max_reaction,
            "iterations_median": float(np.median(its)), "iterations_max": int(its.max()),
            "wall_s": wall, "ms_per_step": 1e3 * wall / max(len(iterations), 1)}


Run = tuple[float, float, float, str, str, str]


def sweep(quick: bool, schemes: Sequence[str] = SCHEMES) -> list[Run]:
    """(dt, E, speed, mesh quality, scheme, motion) of every run. ``quick``: a gentle press and a drag of each
    scheme, and the hardest press of the box (a 1 MPa sliver mesh, the tool jumping 2 cm per step)."""
    if quick:
        return [(0.005, 1e3, 0.1, "regular", s, "press") for s in schemes] + \
               [(0.01, 1e4, 0.1, "regular", s, "drag") for s in schemes] + \
               [(0.02, 1e6, 1.0, "slivers", s, "press") for s in schemes]
    return [(dt, e, v, q, s, m) for m, s, dt, e, v, q in itertools.product(MOTIONS, schemes, DTS, MODULI, SPEEDS,
                                                                              QUALITIES)]


COLOURS = {"stable": "#2e7d32", "unconverged": "#fbc02d", "nonfinite": "#000000", "energy_blowup": "#c62828", "inverted": "#ef6c00",
           "tunnelling": "#6a1b9a", "penetrating": "#1565c0", "buried": "#795548", "no_convergence": "#9e9e9e"}


def plot(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """A map per scheme and motion (rows of panels): dt x E blocks, tool speed x mesh quality cells."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    panels = list(dict.fromkeys((r["scheme"], r.get("motion", "press")) for r in rows))
    dts = sorted({r["dt"] for r in rows})
    moduli = sorted({r["young_modulus"] for r in rows})
    speeds = sorted({r["tool_speed"] for r in rows})
    quals = [q for q in QUALITIES if any(r["mesh_quality"] == q for r in rows)]
    fig, axes = plt.subplots(len(panels), 1, figsize=(1.3 * len(dts) * len(speeds) / 2 + 3, 2.6 * len(panels) + 0.8),
                             squeeze=False)
    for ax, (scheme, motion) in zip(axes[:, 0], panels):
        grid = np.ones((len(moduli) * len(quals), len(dts) * len(speeds), 3))
        for r in rows:
            if (r["scheme"], r.get("motion", "press")) != (scheme, motion):
                continue
            i = moduli.index(r["young_modulus"]) * len(quals) + quals.index(r["mesh_quality"])
            j = dts.index(r["dt"]) * len(speeds) + speeds.index(r["tool_speed"])
            c = COLOURS.get(r["outcome"], "#9e9e9e").lstrip("#")
            grid[i, j] = [int(c[k:k + 2], 16) / 255 for k in (0, 2, 4)]
            lag = float(r.get("lag_end_m", 0.0))
            if lag >= LAG_SHOWN:
                ax.text(j, i, f"{1e3 * lag:.2g}", ha="center", va="center", fontsize=5, color="white")
        ax.imshow(grid, aspect="auto", origin="lower", interpolation="nearest")
        ax.set_xticks([dts.index(d) * len(speeds) + (len(speeds) - 1) / 2 for d in dts],
                      [f"dt {1e3 * d:g} ms" for d in dts], fontsize=7)
        ax.set_yticks([moduli.index(e) * len(quals) + (len(quals) - 1) / 2 for e in moduli],
                      [f"E {e / 1e3:g} kPa" for e in moduli], fontsize=7)
        for b in range(1, len(dts)):
            ax.axvline(b * len(speeds) - 0.5, color="white", lw=2)
        for b in range(1, len(moduli)):
            ax.axhline(b * len(quals) - 0.5, color="white", lw=2)
        what = "press a third deep and hold" if motion == "press" else "press 3 mm, drag 2 cm"
        ax.set_title(f"{scheme}, {what}: cells = tool speed {', '.join(f'{s:g}' for s in speeds)} m/s "
                     f"(left to right) x mesh {', '.join(quals)} (bottom to top); numbers: end lag [mm]", fontsize=8)
    used = sorted({r["outcome"] for r in rows}, key=lambda o: OUTCOMES.index(o) if o in OUTCOMES else 99)
    fig.legend(handles=[Patch(color=COLOURS.get(o, "#9e9e9e"), label=o) for o in used], loc="lower center",
               ncol=len(used), fontsize=7)
    fig.tight_layout(rect=(0, 0.8 / (2.6 * len(panels) + 0.8), 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scheme and motion: the outcome counts, the end lag (median, max over the runs), iterations."""
    out = []
    for scheme, motion in dict.fromkeys((r["scheme"], r["motion"]) for r in rows):
        rs = [r for r in rows if r["scheme"] == scheme and r["motion"] == motion]
        lags = np.array([r["lag_end_m"] for r in rs])
        out.append({"scheme": scheme, "motion": motion, "runs": len(rs),
                    **{o: sum(r["outcome"] == o for r in rs) for o in OUTCOMES},
                    "lag_end_median_mm": 1e3 * float(np.median(lags)), "lag_end_max_mm": 1e3 * float(lags.max()),
                    "its_median": float(np.median([r["iterations_median"] for r in rs])),
                    "its_max": max(r["iterations_max"] for r in rs),
                    "wall_s": float(sum(r["wall_s"] for r in rs))})
    return out


def run_material(out: Path, quick: bool, schemes: Sequence[str] = SCHEMES) -> int:
    from tqdm import tqdm  # noqa: PLC0415

    from .accuracy import format_table  # noqa: PLC0415
    from .refinement import write_csv  # noqa: PLC0415

    runs = sweep(quick, schemes)
    meshes = {q: make_mesh(q) for q in {run[3] for run in runs}}
    rows = []
    with tqdm(total=len(runs), desc="material stability", unit="run", dynamic_ncols=True) as bar:
        for n, (dt, e, v, q, s, m) in enumerate(runs, 1):
            r = run_one(dt, e, v, q, s, mesh=meshes[q], motion=m)
            rows.append(r)
            # a line per run: the full sweep takes a while, and each run's outcome is worth seeing as it comes
            bar.write(f"[{n}/{len(runs)}] {s} {m}, dt {1e3 * dt:g} ms, E {e / 1e3:g} kPa, {v:g} m/s, {q}: "
                      f"{r['outcome']}{' (' + r['detail'] + ')' if r['detail'] else ''}, lag {1e3 * r['lag_end_m']:.3g} mm, "
                      f"its {r['iterations_median']:g}/{r['iterations_max']}, {r['steps_run']} steps in {r['wall_s']:.1f} s")
            bar.update(1)
    write_csv(out / "material_stability.csv", rows)
    plot(out / "material_stability.png", rows)
    print("\nmaterial stability (neo_hookean; ipc = the default, barrier contact; quasi_newton = the former default, "
          "projection contact), first failure per run; the tool's lag at the end [mm] (median, max over runs); "
          "iterations (median of the runs' medians, max):")
    print(format_table(summary(rows), ["scheme", "motion", "runs", *OUTCOMES, "lag_end_median_mm", "lag_end_max_mm",
                                       "its_median", "its_max", "wall_s"]))
    failed = [r for r in rows if r["outcome"] != "stable"]
    if failed:
        print("\nfailures:")
        print(format_table(failed, ["scheme", "motion", "dt", "young_modulus", "tool_speed", "mesh_quality", "outcome",
                                    "failure_step", "detail"]))
    lagging = [r for r in rows if r["lag_end_m"] >= LAG_SHOWN]
    if lagging:
        print(f"\nthe tool stopped {1e3 * LAG_SHOWN:g} mm or more short of its command at the end:")
        print(format_table(lagging, ["scheme", "motion", "dt", "young_modulus", "tool_speed", "mesh_quality",
                                     "lag_end_m", "lag_max_m", "outcome"]))
    print(f"\nwrote {out / 'material_stability.csv'} and {out / 'material_stability.png'}")
    return 0
