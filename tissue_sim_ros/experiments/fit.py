"""Fitting a tissue to a recording, the library behind ``tissue-sim fit`` (no argparse here).

See :mod:`tissue_sim_ros.cli.fit` for the command and what it writes.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError, input_file, output_dir
from ..core.fit.fitting import FitParameter, FitResult, fit, make_parameter
from ..core.fit.tracking import (
    MappedTrackSimulator,
    PointBinding,
    PoolTrackSimulator,
    Recording,
    SceneFactory,
    Schedule,
    SerialTrackSimulator,
    bind_points,
    binding_from_correspondence,
    split_body_name,
)

DEFAULT_FIT = "young_modulus,poisson_ratio"
POINTS_TOPIC = "/tracker/points"
TOOL_TOPIC = "/tool/pose"



@dataclass
class FitSetup:
    """Everything a fit needs, checked: recording, scene values, mesh, binding, schedule, parameters."""

    recording: Recording
    values: dict[str, Any]
    """The scene's flat parameters (shipped defaults, the parameter file, overrides)."""
    mesh: Any
    binding: PointBinding
    schedule: Schedule
    parameters: list[FitParameter]
    n_fit_frames: int

    @property
    def factory(self) -> SceneFactory:
        return SceneFactory(self.values, self.mesh)

    def refined(self) -> SerialTrackSimulator | None:
        """The scene on half the mesh spacing, the points bound to it at rest (None for a mesh from a file)."""
        from ..core.sim.scene import build_simulation  # noqa: PLC0415

        if self.values.get("mesh_file"):
            return None
        values = {**self.values, "spacing": 0.5 * float(self.values["spacing"])}
        sim = build_simulation(values)
        tol = max(0.5 * float(self.values["spacing"]), float(self.binding.outside.max()) + 1e-9)
        binding = bind_points(sim.model.particle_q0, sim.model.tri_indices, self.recording.points[0], tolerance=tol)
        return SerialTrackSimulator(SceneFactory(values, sim.model.mesh), binding, self.schedule)


def read_correspondence(path: str | Path) -> np.ndarray:
    """A correspondence CSV: header 'vertex' or 'triangle,w0,w1,w2', one row per tracked point."""
    path = input_file(path, "--correspondence")
    lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    if not lines:
        raise InputError(f"--correspondence {str(path)!r} is empty")
    header = [h.strip() for h in lines[0].split(",")]
    if header not in (["vertex"], ["triangle", "w0", "w1", "w2"]):
        raise InputError(f"--correspondence {str(path)!r}: header {lines[0]!r}: expected 'vertex' or 'triangle,w0,w1,w2'")
    try:
        return np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], dtype=np.float64).reshape(-1, len(header))
    except ValueError:
        raise InputError(f"--correspondence {str(path)!r}: expected numbers in every row") from None


def prepare(recording: Recording, values: dict[str, Any], names: list[str], *, holdout: float = 0.2,
            bounds: dict[str, tuple[float, float]] | None = None, correspondence: np.ndarray | None = None,
            bind_tolerance: float | None = None) -> FitSetup:
    """Check everything and build the scene, the binding and the schedule (nothing is simulated yet)."""
    from ..core.config import default_params  # noqa: PLC0415
    from ..core.physics.model import SimParams  # noqa: PLC0415
    from ..core.sim.scene import build_simulation  # noqa: PLC0415

    if not (isinstance(holdout, (int, float)) and 0.0 <= holdout < 1.0):
        raise InputError(f"--holdout {holdout!r}: expected a fraction in [0, 1)")
    merged = {**default_params(), **values}
    sim = build_simulation(values)
    params = sim.params
    known = set(SimParams.__dataclass_fields__)
    bases = {n: split_body_name(n) for n in names}
    for n, (base, body) in bases.items():
        if base not in known or not isinstance(getattr(params, base), float):
            raise InputError(f"--fit {n!r}: expected a numeric simulation parameter (e.g. young_modulus, "
                             "poisson_ratio, thickness, density, damping, stiffness_spring)")
        if body is not None and body >= sim.model.n_bodies:
            raise InputError(f"--fit {n!r}: the scene has bodies 0..{sim.model.n_bodies - 1}")
        if body is not None and base in names:
            raise InputError(f"--fit names {base} and {n}: fit the scene's value or per-body ones, not both")
    if params.material == "neo_hookean":
        ignored = [n for n, (b, _) in bases.items() if b in ("stiffness_spring", "stiffness_area", "k_spring",
                                                               "k_area", "mass", "mass_per_area")]
    else:
        ignored = [n for n, (b, _) in bases.items() if b in ("young_modulus", "poisson_ratio", "thickness",
                                                               "density")]
    if ignored:
        raise InputError(f"--fit {','.join(ignored)}: material {params.material} does not use "
                         f"{'it' if len(ignored) == 1 else 'them'}; set material (neo_hookean reads young_modulus, "
                         "poisson_ratio, thickness, density; constraints the stiffnesses and masses)")
    if sim.tool is None:
        raise InputError("the scene has no tool: expected tool_shape and its size in the parameters")
    recording.validate(params.dt)
    mesh = sim.model.mesh
    if correspondence is not None:
        binding = binding_from_correspondence(correspondence, mesh.triangles, mesh.vertices.shape[0])
        if binding.n_points != recording.n_points:
            raise InputError(f"--correspondence has {binding.n_points} rows for {recording.n_points} tracked points: "
                             "expected one row per point")
    else:
        tol = 0.5 * float(merged.get("spacing", 0.0)) if bind_tolerance is None else float(bind_tolerance)
        binding = bind_points(sim.model.particle_q0, sim.model.tri_indices, recording.points[0], tolerance=tol)
    n_fit = recording.n_frames - int(math.floor(holdout * recording.n_frames))
    if n_fit < 3:
        raise InputError(f"{recording.n_frames} frames with --holdout {holdout}: leaves {n_fit} to fit; too short, "
                         "expected at least 3")
    tool_end = float(recording.tool_t_ns[-1] - recording.t_ns[0]) * 1e-9
    if tool_end < 0.5 * recording.duration:
        raise InputError(f"the tool poses end {tool_end:.3f} s after the first frame, the points go on to "
                         f"{recording.duration:.3f} s: expected the tool's trajectory over the recording")
    bounds = bounds or {}
    unknown = set(bounds) - set(names)
    if unknown:
        raise InputError(f"--bounds for {', '.join(sorted(unknown))}, which --fit does not name")
    parameters = [make_parameter(n, float(getattr(params, bases[n][0])), bounds.get(n), kind_of=bases[n][0])
                  for n in names]
    # the scene as the fit will build it: the caller's values, the shipped file underneath
    return FitSetup(recording=recording, values=dict(values), mesh=mesh, binding=binding,
                    schedule=Schedule.from_recording(recording, params.dt), parameters=parameters,
                    n_fit_frames=n_fit)


def run_fit(setup: FitSetup, *, jobs: int = 1, optimizer: str = "least_squares", max_evals: int = 60,
            diff_step: float = 0.1, seed: int = 0, progress: bool = False, slices: int = 9,
            mesh_check: bool = True, backend: str = "local", address: str | None = None) -> FitResult:
    """Fit with a serial simulator (``jobs`` 1) or a pool of ``jobs`` worker processes, or Ray tasks
    (``backend="ray"``, ``address`` of the cluster); the same numbers on each.

    ``mesh_check``: also roll the optimum out on half the mesh spacing and add the estimate's shift there
    to its error bar (not for a mesh from a file).
    """
    from tqdm import tqdm  # noqa: PLC0415

    bar = tqdm(desc="fit", unit="rollout", disable=not progress, mininterval=0.25, leave=False)

    def tick() -> None:
        bar.update(1)

    def on_iter(cost: float) -> None:
        bar.set_postfix_str(f"cost {cost:.4g} mm^2", refresh=False)

    refined = setup.refined() if mesh_check else None
    try:
        sim: Any
        if backend == "ray":
            sim = MappedTrackSimulator(setup.factory, setup.binding, setup.schedule, jobs, backend, address,
                                       on_rollout=tick)
        elif jobs > 1:
            sim = PoolTrackSimulator(setup.factory, setup.binding, setup.schedule, jobs, on_rollout=tick)
        else:
            sim = SerialTrackSimulator(setup.factory, setup.binding, setup.schedule, on_rollout=tick)
        try:
            return fit(sim, setup.recording.points, setup.parameters, n_fit_frames=setup.n_fit_frames,
                       optimizer=optimizer, max_nfev=max_evals, diff_step=diff_step, seed=seed, slices=slices,
                       on_iter=on_iter, refined=refined)
        finally:
            if not isinstance(sim, SerialTrackSimulator):
                sim.close()
    finally:
        bar.close()


# --------------------------------------------------------------------------- outputs


def fitted_config(setup: FitSetup, result: FitResult) -> Any:
    """The scene's resolved configuration with the fitted values (those not identifiable keep their start)."""
    from ..core.config import resolve_config  # noqa: PLC0415

    fitted = {e.name: float(e.value) for e in result.estimates if e.value is not None and "@" not in e.name}
    return resolve_config(overrides=fitted, base=setup.values)


def write_parameter_file(path: Path, cfg: Any, result: FitResult, source: str,
                         moved: tuple[Path, Path] | None = None) -> None:
    """The configuration as a ``tissue_sim_node: ros__parameters:`` YAML, the fit's outcome in comments first.

    ``moved = (staging, final)``: file paths under the staging directory are written as under the final one.
    """
    lines = [f"# tissue-sim fit of {source}",
             f"# RMS tracking error {result.rms_fit_mm:.3f} mm fitted"
             + (f", {result.rms_holdout_mm:.3f} mm held out" if result.rms_holdout_mm is not None else "")]
    for e in result.estimates:
        if e.value is None:
            lines.append(f"# {e.name}: not identifiable ({e.reason}); kept at its start value {e.initial:g}")
        else:
            lines.append(f"# {e.name} = {e.value:.6g} +- {e.sigma:.3g} (95%: {e.low95:.6g} .. {e.high95:.6g})"
                         + ("  (per body: the node takes one value for the scene; not set below)"
                            if "@" in e.name else ""))
    if moved is not None:
        changes = {k: str(moved[1]) + v[len(str(moved[0])):] for k, v in cfg.flat().items()
                   if isinstance(v, str) and v.startswith(str(moved[0]))}
        if changes:
            from ..core.config import resolve_config  # noqa: PLC0415

            cfg = resolve_config(overrides=changes, base={**cfg.flat(), **changes})
    path.write_text("\n".join(lines) + "\n" + cfg.to_yaml())


def write_tracks_csv(path: Path, rec: Recording, simulated: np.ndarray, n_fit: int) -> None:
    f, p = rec.points.shape[:2]
    t = (rec.t_ns - rec.t_ns[0]) * 1e-9
    rows = np.column_stack([np.repeat(np.arange(f), p), np.repeat(t, p), np.tile(np.arange(p), f),
                            rec.points.reshape(-1, 2), simulated.reshape(-1, 2),
                            np.repeat((np.arange(f) >= n_fit).astype(float), p)])
    np.savetxt(path, rows, delimiter=",", comments="", fmt="%.10g",
               header="frame,time_s,point,observed_x,observed_y,simulated_x,simulated_y,held_out")


def result_json(setup: FitSetup, result: FitResult, extra: dict | None = None) -> dict:
    rec = setup.recording
    return {
        "source": rec.source, "frames": rec.n_frames, "points": rec.n_points, "fitted_frames": setup.n_fit_frames,
        "duration_s": rec.duration, "steps": setup.schedule.n_steps,
        "parameters": [e.as_dict() for e in result.estimates],
        "rms_fit_mm": result.rms_fit_mm, "rms_holdout_mm": result.rms_holdout_mm, "cost_mm2": result.cost,
        "residuals": result.n_residuals, "autocorrelation_time": result.tau,
        "relative_singular_values": [float(v) for v in result.singular_values],
        "contact_steps": result.contact_steps, "rollouts": result.n_rollouts, "evaluations": result.n_iterations,
        "optimizer": result.optimizer, "message": result.message, "wall_s": result.wall_time,
        "max_bind_outside_mm": float(setup.binding.outside.max() * 1e3) if setup.binding.n_points else 0.0,
        **(extra or {}),
    }


def summary_lines(setup: FitSetup, result: FitResult, truth: dict | None = None) -> list[str]:
    rec = setup.recording
    out = [f"recording: {rec.n_points} points x {rec.n_frames} frames over {rec.duration:.2f} s, "
           f"{setup.n_fit_frames} fitted, {rec.n_frames - setup.n_fit_frames} held out; "
           f"{setup.schedule.n_steps} steps of {setup.values.get('dt', 'dt')} s"]
    head = f"{'parameter':<16} {'start':>11} {'fitted':>11} {'+-1 sigma':>10} {'95% interval':>25}"
    if truth:
        head += f" {'truth':>11}"
    out.append(head)
    for e in result.estimates:
        if e.value is None:
            row = f"{e.name:<16} {e.initial:>11.5g} {'-':>11} {'-':>10} {'not identifiable':>25}"
        else:
            row = (f"{e.name:<16} {e.initial:>11.5g} {e.value:>11.5g} {e.sigma:>10.3g} "
                   f"{f'{e.low95:.5g} .. {e.high95:.5g}':>25}")
        if truth:
            row += f" {truth.get(e.name, float('nan')):>11.5g}"
        out.append(row)
        if e.value is None:
            out.append(f"  {e.name}: {e.reason}")
    hold = f", held out {result.rms_holdout_mm:.3f} mm" if result.rms_holdout_mm is not None else ""
    out.append(f"RMS tracking error: fitted {result.rms_fit_mm:.3f} mm{hold}")
    out.append(f"{result.optimizer}: {result.n_iterations} evaluations, {result.n_rollouts} rollouts in "
               f"{result.wall_time:.1f} s ({result.message}); residual autocorrelation time {result.tau:.2f}")
    if result.contact_steps == 0:
        out.append("note: the tool never touches the tissue in the fitted part of the recording")
    return out


def write_outputs(out: Path, setup: FitSetup, result: FitResult, *, truth: dict | None = None,
                  extra: dict | None = None, final: Path | None = None) -> list[str]:
    """Write every output into ``out`` (which exists and is empty; ``final``: where it will be renamed to).

    Returns the file names.
    """
    from ..render.fit import plot_cost_slices, plot_point_errors, plot_tracks  # noqa: PLC0415

    rec = setup.recording
    sim_points = result.simulated
    write_parameter_file(out / "fitted.yaml", fitted_config(setup, result), result, rec.source,
                         moved=(out, final.resolve()) if final is not None else None)
    data = result_json(setup, result, extra)
    if truth:
        data["truth"] = truth
    (out / "fit.json").write_text(json.dumps(data, indent=2, default=float) + "\n")
    write_tracks_csv(out / "tracks.csv", rec, sim_points, setup.n_fit_frames)
    t = (rec.t_ns - rec.t_ns[0]) * 1e-9
    names = {e.name: e for e in result.estimates}
    fitted = ", ".join(f"{e.name} {e.value:.4g}" for e in result.estimates if e.value is not None) or "nothing identifiable"
    plot_tracks(out / "tracks.png", t, rec.points, sim_points, setup.n_fit_frames,
                title=f"observed and simulated points ({fitted})")
    plot_point_errors(out / "errors.png", rec.points, sim_points, setup.n_fit_frames,
                      vertices=setup.mesh.vertices, triangles=setup.mesh.triangles,
                      title=f"RMS {result.rms_fit_mm:.2f} mm fitted"
                            + (f", {result.rms_holdout_mm:.2f} mm held out" if result.rms_holdout_mm is not None else ""))
    plot_cost_slices(out / "cost.png", result.slices, names, truth)
    (out / "summary.txt").write_text("\n".join(summary_lines(setup, result, truth)) + "\n")
    return ["fitted.yaml", "fit.json", "tracks.csv", "tracks.png", "errors.png", "cost.png", "summary.txt"]


def staging_dir(out: Path) -> Path:
    """A temporary directory beside ``out`` (same file system, so the final rename is atomic)."""
    if output_dir(out, "--out").exists():
        if any(out.iterdir()):
            raise InputError(f"--out {str(out)!r} exists and is not empty: choose another (nothing is overwritten)")
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    # mkdtemp makes it private (0700); the output is an ordinary directory, as every other command's
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)
    return staging


def missing_parents(out: Path) -> list[Path]:
    """The directories above ``out`` that do not exist yet, deepest first (what :func:`staging_dir` creates)."""
    return [p for p in out.resolve().parents if not p.exists()]


def discard_staging(staging: Path, created: list[Path]) -> None:
    """Remove the staging directory and the ``created`` parents (:func:`missing_parents`): bad input leaves
    nothing behind."""
    shutil.rmtree(staging, ignore_errors=True)
    for d in created:  # deepest first; rmdir: only if still empty
        try:
            d.rmdir()
        except OSError:
            break


def commit_outputs(staging: Path, out: Path) -> None:
    if out.exists():
        out.rmdir()  # empty, checked before
    os.replace(staging, out)


# --------------------------------------------------------------------------- CLI


def make_demo_recording(directory: Path, seed: int = 0) -> tuple[Path, Path, dict]:
    """The demo's scene image, parameter file and recording bag in ``directory``; returns (bag, params, truth)."""
    from ..ros.recording import write_recording  # noqa: PLC0415
    from . import fit_scene as fs  # noqa: PLC0415

    directory.mkdir(parents=True, exist_ok=True)
    image = fs.write_scene_image(directory / "scene.png")
    truth_values = fs.scene_params(image, spacing=fs.RECORDING_SPACING, **fs.TRUTH)
    rec = fs.synthesize(truth_values, n_points=20, noise=5e-4, seed=seed)
    bag = write_recording(directory / "bag", rec.t_ns, rec.points, rec.tool_t_ns, rec.tool_pose,
                          points_topic=POINTS_TOPIC, tool_topic=TOOL_TOPIC)
    from ..core.config import resolve_config  # noqa: PLC0415

    scene = fs.scene_params("scene.png", spacing=fs.FIT_SPACING)
    params = directory / "scene.yaml"
    # the scene's own values only (a partial file, as the shipped scenes): the shipped file fills the rest
    params.write_text("# the demo's scene (experiments/fit_scene.py); image relative to this file\n"
                      + resolve_config(scene, source="the demo scene").to_yaml(names=scene))
    return bag, params, dict(fs.TRUTH)


def load_scene_values(params: str | None, overrides: list[str]) -> dict[str, Any]:
    """The resolved flat configuration of the scene (shipped file < ``params`` < ``overrides``).

    A relative image or mesh path is taken beside the parameter file when it is there (else from the
    working directory) and made absolute, so that fitted.yaml loads from anywhere.
    """
    from ..core.config import load_params_file, parse_assignments, resolve_config  # noqa: PLC0415

    extra = parse_assignments(overrides)
    if params:
        data = load_params_file(params)
        for key in ("image", "mesh_file"):
            v = extra.get(key, data.get(key))
            if isinstance(v, str) and v and not Path(v).is_absolute():
                beside = Path(params).resolve().parent / v
                extra[key] = str(beside if key not in extra and beside.exists() else Path(v).resolve())
    return resolve_config(overrides=extra, params_file=params, source="--set").flat()

