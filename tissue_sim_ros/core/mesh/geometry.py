"""Vectorised plane geometry of a mesh's pieces: triangles' signed areas, points' distances to segments.

One NumPy form of each, which the model, the mesher, mesh quality and tracking share, so their results
agree to the bit (the numba kernels keep their own per-element forms).
"""
from __future__ import annotations

import numpy as np


def signed_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed area of each triangle, 0.5 (x_b - x_a) x (x_c - x_a), positive for counter-clockwise corners.

    ``vertices`` (N, 2), ``triangles`` (T, 3) indices into them; returns (T,), in the vertices' unit squared.
    """
    v, t = np.asarray(vertices), np.asarray(triangles)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


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
