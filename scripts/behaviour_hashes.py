"""Hash what every solver does, to show a refactoring changed no bit of it.

Runs every method x scheme x material x contact model (and the solver options, sleeping, walls, the grasper's
attachments) over a few hundred steps with a tool in the tissue, and the batch rollouts (fused and stepped, serial),
and prints one SHA-256 per run of every step's positions, velocities, prediction, energy terms, residuals,
reaction, contact set and counts. Run it before and after a change that must not change behaviour and compare::

    python scripts/behaviour_hashes.py --out before.json
    python scripts/behaviour_hashes.py --out after.json --compare before.json

Exit code 1 when ``--compare`` finds a run whose hash differs.
"""
from __future__ import annotations

import argparse
import functools
import hashlib
import json
import sys
import time

import numpy as np

from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.contact.tool import ToolPose
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.resources import scene_params_file
from tissue_sim_ros.core.sim.batch import BatchScene, ToolPath, rollout_batch, rollout_candidate
from tissue_sim_ros.core.sim.simulation import Simulation
from tissue_sim_ros.core.timing.trajectories import experiment_a

#: experiment a's poses from just before the first touch to deep in the tissue, then back out
START, STOP = 150, 280

#: the paper scene (config/tissue_sim.yaml, 10 iterations) with each constraint method, scheme and contact model
PAPER = {
    "pbd gs paper": {},
    "pbd gs projection edges": {"contact_model": "projection"},
    "pbd gs projection particles": {"contact_model": "projection", "contact_surface": "particles"},
    "pbd gs abs area": {"area_mode": "abs"},
    "pbd gs abs area projection": {"area_mode": "abs", "contact_model": "projection"},
    "pbd gs none": {"contact_model": "none"},
    "pbd jacobi violated": {"scheme": "jacobi"},
    "pbd jacobi violated projection": {"scheme": "jacobi", "contact_model": "projection"},
    "pbd jacobi all": {"scheme": "jacobi", "jacobi_averaging": "all"},
    "pbd jacobi all projection": {"scheme": "jacobi", "jacobi_averaging": "all", "contact_model": "projection"},
    "xpbd gs": {"method": "xpbd"},
    "xpbd gs projection substeps 3": {"method": "xpbd", "contact_model": "projection", "substeps": 3},
    "xpbd gs paper substeps 2": {"method": "xpbd", "substeps": 2},
    "xpbd jacobi": {"method": "xpbd", "scheme": "jacobi"},
    "xpbd jacobi projection substeps 2": {"method": "xpbd", "scheme": "jacobi", "contact_model": "projection",
                                          "substeps": 2},
    "xpbd damping linear": {"method": "xpbd", "damping": 5.0},
    "pbd damping exponential substeps 2": {"damping": 8.0, "damping_mode": "exponential", "substeps": 2},
    "xpbd walls projection": {"method": "xpbd", "wall_y_bottom": 0.05, "wall_y_top": 0.55,
                              "contact_model": "projection"},
    "pbd jacobi violated walls": {"scheme": "jacobi", "wall_y_bottom": 0.05, "wall_y_top": 0.55},
    "xpbd sleeping": {"method": "xpbd", "sleep_speed": 1e-3},
    "xpbd sleeping projection": {"method": "xpbd", "sleep_speed": 1e-3, "contact_model": "projection"},
}

#: the same with Solver options (the solver factory's keywords)
PAPER_OPTIONS = {
    "xpbd gs parallel partition": ({"method": "xpbd", "contact_model": "projection"}, {"parallel": True}),
    "xpbd gs parallel colour": ({"method": "xpbd"}, {"parallel": True, "parallel_mode": "colour"}),
    "xpbd gs order colour": ({"method": "xpbd"}, {"order": "colour"}),
    "pbd gs order stored": ({}, {"order": "stored"}),
    "xpbd jacobi uniform": ({"method": "xpbd", "scheme": "jacobi", "relaxation": 0.1},
                            {"jacobi_relaxation": "uniform"}),
    "pbd jacobi summed": ({"scheme": "jacobi", "jacobi_averaging": "all", "k_spring": 0.05},
                          {"jacobi_average": False}),
}

#: a 6 x 2 cm neo-Hookean strip pinned at its bottom, a 5 mm capsule pressed 4 mm in, dragged 1 cm and lifted
STRIP = {"material": "neo_hookean", "young_modulus": 20000.0, "poisson_ratio": 0.45, "thickness": 0.01,
         "density": 1000.0, "tool_shape": "capsule", "tool_length": 0.02, "tool_radius": 0.0025, "gravity": -9.8,
         "pin_y_bottom": 0.0005, "boundary_y_top": float("nan"), "boundary_y_bottom": float("nan"),
         "contact_margin": 0.0002, "dt": 0.005}
MATERIAL = {
    "neo quasi_newton": {},
    "neo quasi_newton particles": {"contact_surface": "particles"},
    "neo quasi_newton walls": {"wall_y_top": 0.0199},
    "neo quasi_newton lines": {"boundary_y_bottom": 0.003},
    "neo quasi_newton paper contact": {"contact_model": "paper", "contact_threshold": 0.002, "contact_radius": 0.004},
    "neo quasi_newton sleeping": {"sleep_speed": 1e-4, "sleep_wake_radius": 0.01},
    "neo quasi_newton damping exp": {"damping": 5.0, "damping_mode": "exponential"},
    "neo xpbd gs": {"method": "xpbd"},
    "neo xpbd gs substeps 2": {"method": "xpbd", "substeps": 2, "iterations": 8},
    "neo xpbd jacobi": {"method": "xpbd", "scheme": "jacobi"},
    "neo xpbd walls": {"method": "xpbd", "wall_y_top": 0.0199},
    "neo quasi_newton settle static": {"settle": "static"},
}
MATERIAL_OPTIONS = {
    "neo xpbd gs parallel partition": ({"method": "xpbd"}, {"parallel": True}),
    "neo xpbd jacobi uniform": ({"method": "xpbd", "scheme": "jacobi", "relaxation": 0.3},
                                {"jacobi_relaxation": "uniform"}),
}

#: the grasper on the same strip: close, lift 4 mm, pull sideways, open
GRASPER = {"tool_shape": "grasper", "tool_length": 0.05, "shaft_width": 0.004, "jaw_length": 0.01,
           "grasp_radius": 0.006, "contact_margin": 0.001}
GRASP = {
    "grasper quasi_newton": {},
    "grasper xpbd gs": {"method": "xpbd"},
    "grasper xpbd jacobi": {"method": "xpbd", "scheme": "jacobi"},
    "grasper constraints xpbd": {"material": "constraints", "method": "xpbd", "stiffness_spring": 200.0,
                                 "stiffness_area": 1e5, "mass": 1e-4},
    "grasper constraints pbd walls": {"material": "constraints", "method": "pbd", "wall_y_top": 0.03},
}


class Digest:
    """SHA-256 over arrays and numbers, in the order given."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.touched = 0
        self.grasped = 0

    def add(self, *items) -> None:
        for item in items:
            a = np.ascontiguousarray(np.asarray(item))
            self.h.update(str(a.dtype).encode() + str(a.shape).encode())
            self.h.update(a.tobytes())

    def hex(self) -> str:
        """The hash, with the steps that touched and grasped (a run that never touched tests little)."""
        return f"{self.h.hexdigest()[:16]} touched {self.touched} grasped {self.grasped}"


def _report(d: Digest, sim: Simulation, r) -> None:
    d.touched += bool(len(r.contact_particles))
    d.grasped += bool(len(r.grasped))
    e = r.energy
    d.add(sim.state.particle_q, sim.state.particle_qd, r.x_pred, e.inertial, e.spring, e.area, e.potential,
          getattr(e, "strain", np.zeros(0)), getattr(e, "attach", np.zeros(0)), e.total, r.residual,
          r.reaction_force, r.reaction_torque, r.contact_particles, r.in_contact, r.d_star, r.n_inverted, r.diverged,
          r.solve_iterations, r.solve_residual, r.solve_converged, r.n_penetrating, r.penetration_depth,
          r.n_tunnelled, r.tool_buried, r.grasped, r.attach_force)


def paper_run(values: dict, options: dict | None = None) -> str:
    cfg = resolve_config({"iterations": 10, **values})
    solver = None
    if options:
        from tissue_sim_ros.core.physics.solvers import Solver

        solver = functools.partial(Solver, **options)
    sim = Simulation.from_config(cfg, solver=solver)
    poses = [p for p, _ in experiment_a(sim.tool, sim.params.dt).steps(sim.params.dt)]
    poses = poses[START:STOP] + poses[START:STOP][::-1]
    d = Digest()
    for pose in poses:
        _report(d, sim, sim.step(pose))
    return d.hex()


def strip_sim(values: dict, options: dict | None = None, base: dict | None = None) -> Simulation:
    cfg = resolve_config({**STRIP, **(base or {}), **values})
    solver = None
    if options:
        from tissue_sim_ros.core.physics.solvers import Solver

        solver = functools.partial(Solver, **options)
    return Simulation.from_config(cfg, mesh=mesh_rectangle(0.06, 0.02, 0.0025, origin=(-0.03, 0.0)), solver=solver)


def press_drag_poses(top: float, radius: float) -> list[ToolPose]:
    """Approach from 3 mm above, press 4 mm in (0.2 mm/step), drag 1 cm (0.5 mm/step, turning), lift out."""
    poses = []
    y0 = top + radius + 0.003
    for k in range(35):
        poses.append(ToolPose(0.0, y0 - 0.0002 * k, 0.0))
    y = poses[-1].y
    for k in range(1, 21):
        poses.append(ToolPose(0.0005 * k, y, 0.01 * k))
    x, yaw = poses[-1].x, poses[-1].yaw
    for k in range(1, 31):
        poses.append(ToolPose(x, y + 0.0003 * k, yaw))
    for _ in range(15):
        poses.append(poses[-1])
    return poses


def material_run(values: dict, options: dict | None = None) -> str:
    sim = strip_sim(values, options)
    d = Digest()
    for pose in press_drag_poses(0.02, 0.0025):
        _report(d, sim, sim.step(pose))
    return d.hex()


def grasp_run(values: dict) -> str:
    sim = strip_sim(values, None, GRASPER)
    d = Digest()
    top = 0.02 + 0.0005
    sim.step(ToolPose(0.0, top, 0.0), jaw=0.8)
    for k in range(3):
        _report(d, sim, sim.step(ToolPose(0.0, top, 0.0), jaw=0.8 if k < 2 else 0.0))
    pose = ToolPose(0.0, top, 0.0)
    for k in range(1, 21):
        pose = ToolPose(0.0, top + 0.0002 * k, 0.0)
        _report(d, sim, sim.step(pose))
    for k in range(1, 31):
        pose = ToolPose(-0.0003 * k, pose.y, 0.005 * k)
        _report(d, sim, sim.step(pose))
    for k in range(10):
        _report(d, sim, sim.step(pose, jaw=1.0 if k > 4 else None))
    return d.hex()


def _metrics_digest(d: Digest, result) -> None:
    m = result.metrics()
    d.add(np.array([f"{k}={v!r}" for k, v in sorted(m.items()) if k != "wall_s"]))
    d.add(result.energy)
    if getattr(result, "final_state", None) is not None:
        d.add(result.final_state.particle_q, result.final_state.particle_qd)


def batch_runs() -> dict[str, str]:
    """Fused and stepped rollouts of the held retraction flap and of the pressed strip; rollout_batch serially."""
    from tissue_sim_ros.experiments.retract import grasp_and_lift

    out = {}
    cfg = resolve_config(params_file=[scene_params_file("retract")]).replace(spacing=0.005)
    sim = Simulation.from_config(cfg)
    pose = grasp_and_lift(sim, 10)
    snap = sim.snapshot()
    scratch = BatchScene.from_simulation(sim).build()
    paths = []
    for angle, turn in ((60.0, 0.0), (-30.0, 0.01), (180.0, -0.02)):
        a = np.radians(angle)
        k = np.arange(1, 31)
        paths.append(np.stack([pose.x + 4e-4 * k * np.cos(a), pose.y + 4e-4 * k * np.sin(a), pose.yaw + turn * k],
                              axis=1))
    for fused in (True, False):
        d = Digest()
        for i, p in enumerate(paths):
            _metrics_digest(d, rollout_candidate(scratch, snap, ToolPath(p), i, True, fused=fused))
        out[f"batch retract {'fused' if fused else 'stepped'}"] = d.hex()
    d = Digest()
    res = rollout_batch(sim, paths, final_state=True)
    for r in res.candidates:
        _metrics_digest(d, r)
    d.add(res.baseline_energy)
    out["rollout_batch retract"] = d.hex()
    # the strip pressed (contacts on particles and surface edges)
    strip = strip_sim({})
    for _ in range(3):
        strip.step(ToolPose(0.0, 0.02 + 0.0025 + 0.003, 0.0))
    poses = np.array([[p.x, p.y, p.yaw] for p in press_drag_poses(0.02, 0.0025)[:60]])
    snap = strip.snapshot()
    scratch = BatchScene.from_simulation(strip).build()
    for fused in (True, False):
        d = Digest()
        _metrics_digest(d, rollout_candidate(scratch, snap, ToolPath(poses), 0, True, fused=fused))
        out[f"batch strip {'fused' if fused else 'stepped'}"] = d.hex()
    d = Digest()
    res = rollout_batch(strip, [poses, poses[:40]], final_state=True)
    for r in res.candidates:
        _metrics_digest(d, r)
    d.add(res.baseline_energy)
    out["rollout_batch strip"] = d.hex()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write the hashes as JSON here")
    ap.add_argument("--compare", help="a JSON of hashes to compare with")
    ap.add_argument("--only", help="run only the runs whose name contains this")
    args = ap.parse_args(argv)
    runs = {}
    for name, values in PAPER.items():
        runs[name] = functools.partial(paper_run, values)
    for name, (values, options) in PAPER_OPTIONS.items():
        runs[name] = functools.partial(paper_run, values, options)
    for name, values in MATERIAL.items():
        runs[name] = functools.partial(material_run, values)
    for name, (values, options) in MATERIAL_OPTIONS.items():
        runs[name] = functools.partial(material_run, values, options)
    for name, values in GRASP.items():
        runs[name] = functools.partial(grasp_run, values)
    hashes: dict[str, str] = {}
    for name, run in runs.items():
        if args.only and args.only not in name:
            continue
        t = time.perf_counter()
        hashes[name] = run()
        print(f"{name:<45} {hashes[name]}  {time.perf_counter() - t:6.1f} s", flush=True)
    if not args.only or "batch" in args.only:
        t = time.perf_counter()
        for name, h in batch_runs().items():
            hashes[name] = h
            print(f"{name:<45} {h}", flush=True)
        print(f"(batch runs {time.perf_counter() - t:.1f} s)")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(hashes, f, indent=1)
    if args.compare:
        with open(args.compare) as f:
            before = json.load(f)
        differ = [k for k in hashes if k in before and before[k] != hashes[k]]
        missing = [k for k in before if k not in hashes and (not args.only or args.only in k)]
        print(f"{len(hashes) - len(differ)} of {len(hashes)} equal" + (f"; differ: {differ}" if differ else "")
              + (f"; not run: {missing}" if missing else ""))
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
