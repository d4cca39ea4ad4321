"""The tissue image: reading it (size-guarded) and its binary tissue mask (threshold, small
regions and holes dropped as noise)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, input_file

#: Images larger than this many pixels are refused (memory and time grow with the pixel count).
MAX_PIXELS = 50_000_000


#: Tissue regions and holes with fewer pixels than this are treated as image noise (dropped / filled).
MIN_REGION_PX = 16


def read_image(image: str | Path | np.ndarray, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """Read an image file (PNG/JPEG/BMP/...) or check an array; returns grey (H, W) or BGR (H, W, 3) uint8.

    Raises InputError for a missing file, a file OpenCV cannot decode, a wrong
    array shape, or more than ``max_pixels`` pixels.
    """
    import cv2  # noqa: PLC0415  (OpenCV only when an image is meshed)

    if isinstance(image, np.ndarray):
        name = f"image array of shape {image.shape}"
        img = image
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))) or min(img.shape[:2]) < 2:
            raise InputError(f"{name}: expected a grey (H, W) or BGR (H, W, 3) image of at least 2 x 2 pixels")
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if img.shape[0] * img.shape[1] > max_pixels:
            raise InputError(f"{name} has {img.shape[0] * img.shape[1]} pixels: the limit is {max_pixels}")
        if img.dtype != np.uint8:
            if np.issubdtype(img.dtype, np.floating) and np.nanmax(img) <= 1.0:
                img = img * 255.0
            img = np.clip(np.nan_to_num(img), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(img)
    path = input_file(image, "image file")
    # check the size from the header before decoding a huge image into memory
    header_size = _image_header_size(path)
    if header_size is not None and header_size[0] * header_size[1] > max_pixels:
        raise InputError(f"image {str(path)!r} is {header_size[1]} x {header_size[0]} = "
                         f"{header_size[0] * header_size[1]} pixels: the limit is {max_pixels}")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{str(path)!r} is not an image OpenCV can read: expected a PNG, JPEG or BMP file")
    if img.shape[0] * img.shape[1] > max_pixels:
        raise InputError(f"image {str(path)!r} has {img.shape[0] * img.shape[1]} pixels: the limit is {max_pixels}")
    return img


def _image_header_size(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG/BMP header without decoding, or None if unknown."""
    with open(path, "rb") as f:
        head = f.read(32)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24:
        return int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")
    if head[:2] == b"BM" and len(head) >= 26:
        return abs(int.from_bytes(head[22:26], "little", signed=True)), int.from_bytes(head[18:22], "little", signed=True)
    return None


def tissue_mask(image: str | Path | np.ndarray, *, threshold: float | None = None,
                tissue_color: tuple[int, int, int] | None = None, color_tolerance: float = 40.0,
                min_region_px: int = MIN_REGION_PX, max_pixels: int = MAX_PIXELS,
                name: str | None = None) -> np.ndarray:
    """Which pixels are tissue, shape (H, W), bool.

    Tissue is what differs from the background, decided by (in order of precedence)

    * ``tissue_color`` (B, G, R): pixels whose every channel is within ``color_tolerance`` of it;
    * ``threshold``: grey level in [0, 255]; the side of the threshold holding most of the
      image border is background;
    * neither: Otsu's threshold on the grey image, background side again from the border.

    Regions and holes with fewer than ``min_region_px`` pixels are image noise: dropped / filled.
    ``name`` names the image in error messages (default: its path).
    """
    import cv2  # noqa: PLC0415

    img = read_image(image, max_pixels=max_pixels)
    if name is None:
        name = f"image {str(image)!r}" if not isinstance(image, np.ndarray) else "image array"
    if tissue_color is not None:
        color = np.asarray(tissue_color, dtype=np.float64).ravel()
        if color.size != 3 or not np.all((color >= 0) & (color <= 255)):
            raise InputError(f"tissue colour {tissue_color!r}: expected B,G,R in [0, 255]")
        bgr = img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        mask = np.all(np.abs(bgr.astype(np.int16) - color.astype(np.int16)) <= color_tolerance, axis=2)
    else:
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if threshold is None:
            if int(grey.max()) == int(grey.min()):
                raise InputError(f"{name} is one flat grey level ({int(grey.min())}): expected tissue that "
                                 "differs from the background")
            t, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            # Otsu always splits; on an image of noise alone the two classes overlap. Tissue on a
            # background gives classes many standard deviations apart (>= 8 on the shipped image).
            g = grey.astype(np.float64)
            lo_c, hi_c = g[g <= t], g[g > t]
            sep = abs(hi_c.mean() - lo_c.mean()) / max(np.sqrt(0.5 * (lo_c.var() + hi_c.var())), 1e-9)
            if sep < 4.0:
                raise InputError(f"{name} has no clear tissue: Otsu's threshold {t:g} splits the grey levels into "
                                 f"classes only {sep:.1f} standard deviations apart (expected >= 4); "
                                 "give a threshold or a tissue colour")
        else:
            t = float(threshold)
            if not 0 <= t <= 255:
                raise InputError(f"threshold {threshold!r}: expected a grey level in [0, 255]")
        above = grey > t
        border = np.concatenate([above[0], above[-1], above[1:-1, 0], above[1:-1, -1]])
        # the background is the class that owns most of the image border
        mask = ~above if border.mean() > 0.5 else above
    mask = _drop_small(mask, min_region_px)
    mask = ~_drop_small(~mask, min_region_px)
    if not mask.any():
        how = (f"colour {tuple(tissue_color)} +- {color_tolerance}" if tissue_color is not None
               else f"grey threshold {threshold}" if threshold is not None else "Otsu's threshold")
        raise InputError(f"{name} has no tissue ({how} leaves no region of >= {min_region_px} pixels): "
                         "expected tissue that differs from the background")
    return mask


def _drop_small(mask: np.ndarray, min_px: int) -> np.ndarray:
    """``mask`` without 8-connected regions of fewer than ``min_px`` pixels."""
    import cv2  # noqa: PLC0415

    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    return keep[labels]
