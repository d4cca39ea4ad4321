#!/usr/bin/env python3
"""Draw the default tissue image, config/tissue.png (deterministic: no randomness).

Two tissues like the paper's Fig. 1 on a white background, 500 x 500 px at
0.002 m/px (a 1 m x 1 m world with the origin at the bottom-left corner):

* the upper tissue hangs from a flat top edge at y = 0.98 m; its lower edge is
  wavy, between y ~ 0.62 and 0.68 m;
* the lower tissue rests on a flat bottom edge at y = 0.02 m; its upper edge is
  wavy, between y ~ 0.34 and 0.40 m;
* both span x = 0.05 .. 0.95 m, leaving a gap around y ~ 0.51 m where a tool
  can enter from the side.

The wavy edges are sums of a few sines (smooth, irregular). Tissue is pink with
a darker rim and faint vessels, all far darker than the white background so
Otsu's threshold separates it cleanly.

Usage: python scripts/draw_default_tissue.py [--out config/tissue.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

SIZE_PX = 500
SCALE = 0.002  # m per pixel
X0, X1 = 0.05, 0.95  # tissue x extent [m]
TOP, BOTTOM = 0.98, 0.02  # flat outer edges [m]
UPPER_EDGE_MID, LOWER_EDGE_MID = 0.65, 0.37  # mean y of the wavy facing edges [m]
WAVE = 0.03  # half the peak-to-peak height of the facing edges [m]
TISSUE_BGR = (150, 135, 225)  # pink
RIM_BGR = (95, 80, 185)  # darker rim
VESSEL_BGR = (120, 100, 205)


def wavy(x: np.ndarray, phase: float) -> np.ndarray:
    """A smooth irregular profile in [-1, 1] over x [m]."""
    w = (0.55 * np.sin(2 * np.pi * x / 0.61 + phase) + 0.3 * np.sin(2 * np.pi * x / 0.23 + 2.1 * phase + 0.7)
         + 0.15 * np.sin(2 * np.pi * x / 0.11 + 0.4 - phase))
    return w / np.max(np.abs(w))


def to_px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """World [m] -> continuous pixel coordinates (col, row); rows point down."""
    return np.stack([x / SCALE, SIZE_PX - y / SCALE], axis=1)


def tissue_polygon(flat_y: float, edge_mid: float, phase: float) -> np.ndarray:
    """Closed polygon (n, 2) [px]: a flat outer edge and a wavy facing edge, with rounded corners."""
    x = np.linspace(X0, X1, 400)
    edge = edge_mid + WAVE * wavy(x, phase)
    # round the corners where the wavy edge meets the sides (radius ~ 0.04 m)
    r = 0.04
    sign = 1.0 if flat_y > edge_mid else -1.0  # the wavy edge is below (upper tissue) or above (lower tissue)
    t = np.clip(np.minimum(x - X0, X1 - x) / r, 0.0, 1.0)
    edge = edge + sign * r * (1.0 - np.sqrt(1.0 - (1.0 - t) ** 2))
    xs = np.concatenate([[X0], x, [X1]])
    ys = np.concatenate([[flat_y], edge, [flat_y]])
    return to_px(xs, ys)


def draw(out: Path) -> None:
    img = np.full((SIZE_PX, SIZE_PX, 3), 255, dtype=np.uint8)
    shift = 4
    for flat_y, mid, phase in ((TOP, UPPER_EDGE_MID, 0.3), (BOTTOM, LOWER_EDGE_MID, 2.2)):
        poly = tissue_polygon(flat_y, mid, phase)
        pts = np.round(poly * (1 << shift)).astype(np.int32)
        cv2.fillPoly(img, [pts], TISSUE_BGR, lineType=cv2.LINE_AA, shift=shift)
        cv2.polylines(img, [pts], True, RIM_BGR, thickness=3, lineType=cv2.LINE_AA, shift=shift)
        # faint vessels running along the tissue, inside it
        x = np.linspace(X0 + 0.08, X1 - 0.08, 200)
        for k, frac in enumerate((0.3, 0.65)):
            y = flat_y + frac * (mid - flat_y) + 0.012 * np.sin(2 * np.pi * x / (0.3 + 0.07 * k) + phase)
            v = np.round(to_px(x, y) * (1 << shift)).astype(np.int32)
            cv2.polylines(img, [v], False, VESSEL_BGR, thickness=2, lineType=cv2.LINE_AA, shift=shift)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), img):
        raise SystemExit(f"could not write {out}")
    print(f"wrote {out} ({SIZE_PX} x {SIZE_PX} px, {SCALE} m/px)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent.parent / "config" / "tissue.png")
    draw(parser.parse_args().out)


if __name__ == "__main__":
    main()
