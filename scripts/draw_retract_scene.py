"""Draw the retraction scene's tissue image, config/scenes/retract.png (deterministic).

A flap of soft tissue at real size: 400 x 200 px at 0.2 mm/px (an 8 cm x 4 cm world, origin at the
bottom-left corner). The flap is a 6 cm x 1.2 cm slab, x = 1 .. 7 cm, y = 0.4 .. 1.6 cm, with sharp corners;
its underside (y = 0.4 cm) is held (``boundary_y_bottom``), the rest is free, and above it is free space where
the grasper comes in. Tissue is dark red on a white background so Otsu's threshold separates it.

Usage: python scripts/draw_retract_scene.py [--out config/scenes/retract.png]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

WIDTH_PX, HEIGHT_PX = 400, 200
SCALE = 2e-4  # m per pixel
X0, X1 = 0.010, 0.070  # flap x extent [m]
BOTTOM, TOP = 0.004, 0.016  # flap y extent [m]
TISSUE_BGR = (60, 50, 150)


def draw() -> np.ndarray:
    img = np.full((HEIGHT_PX, WIDTH_PX, 3), 255, dtype=np.uint8)
    # pixel rows count down from the top; world y up from the bottom
    c0, c1 = int(round(X0 / SCALE)), int(round(X1 / SCALE))
    r0, r1 = HEIGHT_PX - int(round(TOP / SCALE)), HEIGHT_PX - int(round(BOTTOM / SCALE))
    img[r0:r1, c0:c1] = TISSUE_BGR
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "config" / "scenes" / "retract.png"))
    args = ap.parse_args()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, draw())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
