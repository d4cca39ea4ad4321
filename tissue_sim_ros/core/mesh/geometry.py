"""Vectorised plane geometry of a mesh's pieces: points' distances to segments.

One NumPy form of each, which the mesher and tracking share, so their results agree to the bit.
"""
from __future__ import annotations

import numpy as np


def segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point (P, 2) to each segment a -> b (a and b (M, 2)): shape (P, M).

    A zero-length segment is its point. The (P, M, 2) temporaries are the caller's to bound (chunks of points).
    """
    ab = b - a
    ll = np.maximum((ab * ab).sum(axis=1), 1e-300)
    d = points[:, None, :] - a[None, :, :]
    s = np.clip((d * ab[None]).sum(axis=2) / ll[None], 0.0, 1.0)
    e = d - s[..., None] * ab[None]
    return np.sqrt((e * e).sum(axis=2))
