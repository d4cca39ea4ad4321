"""A real-size scene for material fits, and recordings of it made by the simulator.

The scene: a 100 mm x 40 mm block of soft tissue (``material: neo_hookean``,
5 mm thick, 1000 kg/m^3) resting on a plate (its bottom edge pinned), drawn as
an image so that the mesh spacing is a parameter. At the first frame the
tissue is released from its drawn (stress-free) shape and settles under its
weight, by an amount that falls as 1/E; a 16 mm ball, 1 mm above the top
surface at the middle, presses 8 mm below that surface and lifts off again
(1.5 s each way, 300 steps of 10 ms). A camera tracks points on the tissue at
30 Hz, 4 ms off the simulation's steps; the robot reports the tool pose at
125 Hz.

Why the weight matters: where the tool prescribes the tissue's displacement,
a linear elastic body's displacement field does not depend on Young's modulus
(E scales the forces only), so the positions tell E only through a load the
tissue carries itself, its weight (and its inertia), against its density.
Poisson's ratio shapes the field around the ball (the bulge beside it).

:func:`synthesize` makes a recording of that run with known parameters (any
mesh spacing, Gaussian noise on the tracked points) as arrays; the ROS layer
(:func:`tissue_sim_ros.ros.recording.write_recording`) writes it as a real bag.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core.contact.tool import WaypointTrajectory
from ..core.errors import InputError

#: The block [m] as (x0, y0, x1, y1).
BLOCK = (-0.05, 0.0, 0.05, 0.04)
#: Image scale [m per pixel] and the image's extent [m] (background all round).
SCALE = 2e-4
IMAGE_LO = (-0.06, -0.01)
IMAGE_HI = (0.06, 0.05)
#: Indenter: a ball of this radius [m] at x = BALL_X, GAP above the top surface, pressed DEPTH below it [m],
#: PHASE seconds down and as long up.
BALL_RADIUS = 0.008
BALL_X = 0.0
DEPTH = 0.008
GAP = 0.001
PHASE = 1.5
#: Mesh spacing of the recordings [m] and of the fits [m]: a fit never sees the mesh the truth was made on.
RECORDING_SPACING = 0.0025
FIT_SPACING = 0.004
#: The truth of the demo and the benchmark.
TRUTH = {"young_modulus": 5e3, "poisson_ratio": 0.30}
#: Where the demo's fit starts.
START = {"young_modulus": 2e3, "poisson_ratio": 0.45}


def _inside(p: np.ndarray, margin: float) -> np.ndarray:
    """True for points at least ``margin`` inside the block's outline."""
    r = BLOCK
    return (p[:, 0] >= r[0] + margin) & (p[:, 0] <= r[2] - margin) & (p[:, 1] >= r[1] + margin) & \
        (p[:, 1] <= r[3] - margin)


def write_scene_image(path: str | Path) -> Path:
    """The tissue as a PNG: dark on white."""
    import cv2  # noqa: PLC0415

    w = int(round((IMAGE_HI[0] - IMAGE_LO[0]) / SCALE))
    h = int(round((IMAGE_HI[1] - IMAGE_LO[1]) / SCALE))
    img = np.full((h, w), 255, np.uint8)
    for x0, y0, x1, y1 in (BLOCK,):
        c0, c1 = int(round((x0 - IMAGE_LO[0]) / SCALE)), int(round((x1 - IMAGE_LO[0]) / SCALE))
        r0, r1 = h - int(round((y1 - IMAGE_LO[1]) / SCALE)), h - int(round((y0 - IMAGE_LO[1]) / SCALE))
        img[r0:r1, c0:c1] = 60
    path = Path(path)
    if not cv2.imwrite(str(path), img):
        raise InputError(f"could not write the scene image {str(path)!r}")
    return path


def scene_params(image: str | Path, spacing: float = 0.004, **overrides: Any) -> dict[str, Any]:
    """Flat parameters of the scene (the keys of config/tissue_sim.yaml)."""
    values: dict[str, Any] = {
        "image": str(image), "spacing": float(spacing), "scale": SCALE,
        "origin_x": IMAGE_LO[0], "origin_y": IMAGE_LO[1], "threshold": -1.0,
        "boundary_y_top": 1.0, "boundary_y_bottom": 0.25 * spacing,  # no top line: 1 m is far above
        "material": "neo_hookean", "method": "xpbd", "contact_model": "projection", "substeps": 10,
        "iterations": 10, "dt": 0.01, "thickness": 0.005, "density": 1000.0, "damping": 0.0,
        "young_modulus": START["young_modulus"], "poisson_ratio": START["poisson_ratio"],
        "tool_shape": "sphere", "tool_radius": BALL_RADIUS,
    }
    values.update(overrides)
    return values


def sample_points(n: int, rng: np.random.Generator, margin: float = 0.002) -> np.ndarray:
    """``n`` points uniformly on the tissue, at least ``margin`` inside its outline [m], shape (n, 2)."""
    out = np.empty((0, 2))
    lo = np.array(BLOCK[:2])
    hi = np.array(BLOCK[2:])
    while out.shape[0] < n:
        p = lo + rng.random((4 * n, 2)) * (hi - lo)
        out = np.concatenate([out, p[_inside(p, margin)]])
    return out[:n]


def indenter_trajectory() -> WaypointTrajectory:
    """The ball from just above the top surface to DEPTH below it and back, PHASE seconds each way."""
    y_top = BLOCK[3] + BALL_RADIUS + GAP
    y_low = BLOCK[3] + BALL_RADIUS - DEPTH
    times = np.array([0.0, PHASE, 2 * PHASE])
    poses = np.array([[BALL_X, y_top, 0.0], [BALL_X, y_low, 0.0], [BALL_X, y_top, 0.0]])
    return WaypointTrajectory(times, poses)


@dataclass
class SyntheticRecording:
    """A simulated recording: what a tracker and a robot would have logged."""

    t_ns: np.ndarray
    """Observation stamps [ns], shape (F,)."""
    points: np.ndarray
    """Observed (noisy) tracked points [m], shape (F, P, 2)."""
    truth_points: np.ndarray
    """The same without noise [m], shape (F, P, 2)."""
    tool_t_ns: np.ndarray
    """Tool pose stamps [ns], shape (M,)."""
    tool_pose: np.ndarray
    """Tool poses (x, y, yaw), shape (M, 3)."""
    values: dict[str, Any]
    """The parameters it was made with."""
    contact_steps: int


def synthesize(values: Mapping[str, Any], *, n_points: int = 20, noise: float = 5e-4, seed: int = 0,
               duration: float | None = None, camera_rate: float = 30.0, camera_offset: float = 0.004,
               tool_rate: float = 125.0, t0_ns: int = 1_700_000_000_000_000_000) -> SyntheticRecording:
    """Simulate the indentation with ``values`` and record it as a tracker and a robot would.

    Points are drawn uniformly on the tissue (:func:`sample_points`, the same points at any spacing for a
    seed), followed by barycentric coordinates in this simulation's mesh, sampled at ``camera_rate``
    (first frame at the rest state, later ones ``camera_offset`` s off the steps), with Gaussian noise of
    ``noise`` m per coordinate from frame 1 on (frame 0 is where the points were picked).
    """
    from ..core.fit.tracking import Recording, Schedule, bind_points, rollout_tracks  # noqa: PLC0415
    from ..core.sim.scene import build_simulation  # noqa: PLC0415

    rng = np.random.default_rng(seed)
    sim = build_simulation(dict(values))
    mesh = sim.model.mesh
    traj = indenter_trajectory()
    duration = traj.duration if duration is None else float(duration)
    pts = sample_points(n_points, rng)
    binding = bind_points(mesh.vertices, mesh.triangles, pts, tolerance=float(values.get("spacing", 0.004)))
    period = 1.0 / camera_rate
    t_obs = [0.0] + list(np.arange(camera_offset + period, duration + 1e-12, period))
    t_obs_ns = t0_ns + np.round(np.array(t_obs) * 1e9).astype(np.int64)
    t_tool = np.arange(0.0, duration + 1e-12, 1.0 / tool_rate)
    if t_tool[-1] < duration - 1e-9:
        t_tool = np.append(t_tool, duration)
    tool_pose = np.array([traj.pose_at(float(t)).as_array() for t in t_tool])
    tool_t_ns = t0_ns + np.round(t_tool * 1e9).astype(np.int64)
    rec = Recording(t_obs_ns, np.zeros((len(t_obs), n_points, 2)), tool_t_ns, tool_pose)
    schedule = Schedule.from_recording(rec, sim.params.dt)
    run = rollout_tracks(sim, binding, schedule, len(t_obs))
    observed = run.points.copy()
    observed[1:] += rng.normal(0.0, noise, observed[1:].shape)
    return SyntheticRecording(t_ns=t_obs_ns, points=observed, truth_points=run.points, tool_t_ns=tool_t_ns,
                              tool_pose=tool_pose, values=dict(values), contact_steps=run.contact_steps)
