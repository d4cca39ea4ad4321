#!/usr/bin/env python3
"""Draw the real-size scene's tissue image, config/scenes/liver_probe.png (deterministic).

A cross-section of a liver lobe's edge resting on a support, at real size:
400 x 250 px at 0.2 mm/px (an 8 cm x 5 cm world, origin at the bottom-left
corner):

* the slab spans x = 1 .. 7 cm; its flat underside lies on y = 0.4 cm (the
  support: ``boundary_y_bottom`` pins the particles there);
* its upper surface is a low dome, 2.6 cm above the support at the sides and
  3.0 cm in the middle, with rounded upper corners (radius 5 mm);
* above it is free space where the instrument comes in.

Tissue is dark red on a white background so Otsu's threshold separates it.

Usage: python scripts/draw_liver_scene.py [--out config/scenes/liver_probe.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

WIDTH_PX, HEIGHT_PX = 400, 250
SCALE = 2e-4  # m per pixel
X0, X1 = 0.010, 0.070  # slab x extent [m]
BOTTOM = 0.004  # the support [m]
TOP_SIDE, TOP_MID = 0.030, 0.034  # upper surface height at the sides and in the middle [m]
CORNER = 0.005  # radius of the rounded upper corners [m]
TISSUE_BGR = (60, 50, 150)


def top(x: np.ndarray) -> np.ndarray:
    """Height of the upper surface [m]: a parabola from TOP_SIDE at the sides to TOP_MID in the middle."""
    s = (x - 0.5 * (X0 + X1)) / (0.5 * (X1 - X0))
    return TOP_SIDE + (TOP_MID - TOP_SIDE) * (1.0 - s * s)


def outline() -> np.ndarray:
    """Closed outline of the slab in world coordinates [m], counter-clockwise, (K, 2)."""
    xs = np.linspace(X0 + CORNER, X1 - CORNER, 200)
    upper = np.stack([xs, top(xs)], axis=1)[::-1]  # right to left
    a = np.linspace(0.0, 0.5 * np.pi, 20)
    right = np.stack([X1 - CORNER + CORNER * np.cos(a), top(np.array([X1 - CORNER]))[0] - CORNER + CORNER * np.sin(a)],
                     axis=1)
    left = np.stack([X0 + CORNER - CORNER * np.sin(a), top(np.array([X0 + CORNER]))[0] - CORNER + CORNER * np.cos(a)],
                    axis=1)
    return np.vstack([[X0, BOTTOM], [X1, BOTTOM], right, upper, left])


def draw() -> np.ndarray:
    img = np.full((HEIGHT_PX, WIDTH_PX, 3), 255, np.uint8)
    p = outline()
    px = np.stack([p[:, 0] / SCALE, HEIGHT_PX - p[:, 1] / SCALE], axis=1)
    cv2.fillPoly(img, [np.round(px * 16).astype(np.int32)], TISSUE_BGR, lineType=cv2.LINE_AA, shift=4)
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "config" / "scenes" / "liver_probe.png"))
    args = ap.parse_args()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, draw())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
