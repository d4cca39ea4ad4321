"""The environments' pictures: the deformed mesh, the tool, tracked points and goals, drawn with OpenCV.

Not in ``render/``: that package draws publication figures with Matplotlib and selects the Agg backend when it is
imported, which an RL user's own plotting (often interactive) must not inherit from a ``render()`` call, and a
frame every step wants a rasteriser rather than a figure.

``human`` mode shows the frames in a Tk window (the standard library's ``tkinter``; the project's
opencv-python-headless has no windows of its own). Where there is no display it is refused when the environment
is made, with one line saying why.
"""
from __future__ import annotations

import math
import os

import cv2
import numpy as np

from ..core.contact.tool import ToolPose, ToolShape
from ..core.errors import InputError

#: colours (RGB): tissue fill per body, its wire, the tool, tracked points, goals, held particles
TISSUE = [(229, 143, 160), (217, 102, 125), (242, 184, 198), (201, 79, 109)]
WIRE = (122, 40, 56)
TOOL = (70, 70, 70)
POINT = (21, 101, 192)
GOAL = (255, 193, 7)
ACHIEVED = (46, 125, 50)
HELD = (0, 188, 212)
BACKGROUND = (255, 255, 255)
SHIFT = 4  # sub-pixel bits of cv2's drawing: vertices at 1/16 px
SCALE = float(1 << SHIFT)


def _to_pixels(p: np.ndarray, bounds: tuple[float, float, float, float], size: tuple[int, int]) -> np.ndarray:
    """World points (..., 2) [m] -> fixed-point pixel coordinates (..., 2) int32 (y up in the world, down in the
    image), the view fitted into the frame at one scale."""
    x0, x1, y0, y1 = bounds
    w, h = size
    s = min(w / max(x1 - x0, 1e-12), h / max(y1 - y0, 1e-12))
    ox = 0.5 * (w - s * (x1 - x0))
    oy = 0.5 * (h - s * (y1 - y0))
    px = (ox + (p[..., 0] - x0) * s) * SCALE
    py = (h - oy - (p[..., 1] - y0) * s) * SCALE
    return np.stack([px, py], axis=-1).round().astype(np.int32)


def draw_frame(model, x: np.ndarray, tool: ToolShape | None, pose: ToolPose | None, jaw: float, *,
               goals: np.ndarray | None = None, achieved: np.ndarray | None = None, points: np.ndarray | None = None,
               held: np.ndarray | None = None, bounds: tuple[float, float, float, float],
               size: tuple[int, int] = (480, 320), tolerance: float = 0.0) -> np.ndarray:
    """One frame (H, W, 3) uint8 RGB: tissue (filled per body, wire), tracked points (blue), held particles (cyan),
    the goals (yellow rings of radius ``tolerance``, at least 4 px) and the achieved points (green), the tool."""
    w, h = size
    img = np.full((h, w, 3), BACKGROUND, dtype=np.uint8)
    tris = np.asarray(model.tri_indices)
    if tris.shape[0]:
        polys = _to_pixels(x[tris], bounds, size)
        body = np.asarray(model.tri_body)
        for b in np.unique(body):
            cv2.fillPoly(img, list(polys[body == b]), TISSUE[int(b) % len(TISSUE)], cv2.LINE_AA, SHIFT)
        cv2.polylines(img, list(polys), True, WIRE, 1, cv2.LINE_AA, SHIFT)
    scale = _to_pixels(np.array([[bounds[0], 0.0], [bounds[0] + 1.0, 0.0]]), bounds, size)
    px_per_m = (scale[1, 0] - scale[0, 0]) / SCALE
    if points is not None:
        for p in _to_pixels(points, bounds, size):
            cv2.circle(img, tuple(int(v) for v in p), int(2 * SCALE), POINT, -1, cv2.LINE_AA, SHIFT)
    if held is not None and len(held):
        for p in _to_pixels(x[np.asarray(held)], bounds, size):
            cv2.circle(img, tuple(int(v) for v in p), int(2 * SCALE), HELD, -1, cv2.LINE_AA, SHIFT)
    ring = max(4.0, tolerance * px_per_m)
    if goals is not None:
        for p in _to_pixels(goals, bounds, size):
            cv2.circle(img, tuple(int(v) for v in p), int(ring * SCALE), GOAL, 2, cv2.LINE_AA, SHIFT)
    if achieved is not None:
        for p in _to_pixels(achieved, bounds, size):
            cv2.circle(img, tuple(int(v) for v in p), int(3 * SCALE), ACHIEVED, -1, cv2.LINE_AA, SHIFT)
    if tool is not None and pose is not None:
        local = tool.outline(jaw if tool.kind == "grasper" else None)
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        world = local @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])
        poly = _to_pixels(world, bounds, size)
        if tool.kind == "grasper":  # shaft and jaws as one open line: the jaws are blades, not a filled area
            cv2.polylines(img, [poly], False, TOOL, 2, cv2.LINE_AA, SHIFT)
        else:
            cv2.fillPoly(img, [poly], TOOL, cv2.LINE_AA, SHIFT)
    return img


def display_available() -> str:
    """Why ``human`` rendering cannot show a window here ("" when it can)."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    try:
        import tkinter  # noqa: F401, PLC0415
    except ImportError:
        return "Python's tkinter is not installed (Debian: apt-get install python3-tk)"
    return ""


class FrameWindow:
    """A Tk window showing RGB frames (``human`` rendering). InputError where no window can be opened."""

    def __init__(self, title: str, width: int, height: int) -> None:
        why = display_available()
        if why:
            raise InputError(f"render_mode='human': {why}; expected a desktop session, or render_mode='rgb_array'")
        import tkinter  # noqa: PLC0415

        try:
            self.root = tkinter.Tk()
        except tkinter.TclError as exc:
            raise InputError(f"render_mode='human': cannot open a window ({exc}); expected a desktop session, or "
                             "render_mode='rgb_array'") from None
        self.root.title(title)
        self.label = tkinter.Label(self.root)
        self.label.pack()
        self._image = None
        self._tk = tkinter

    def show(self, frame: np.ndarray) -> None:
        """Show ``frame`` (H, W, 3) uint8 RGB now (as a PPM image: no image library needed)."""
        h, w = frame.shape[:2]
        ppm = f"P6 {w} {h} 255 ".encode() + np.ascontiguousarray(frame).tobytes()
        self._image = self._tk.PhotoImage(data=ppm, format="PPM")
        self.label.configure(image=self._image)
        self.root.update_idletasks()
        self.root.update()

    def close(self) -> None:
        try:
            self.root.destroy()
        except self._tk.TclError:
            pass
