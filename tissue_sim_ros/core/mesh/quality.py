"""Mesh quality: interior angles, area error against the image, per-body counts
(``tissue-sim mesh`` prints them)."""
from __future__ import annotations

import numpy as np

from .geometry import signed_areas
from .types import TissueMesh


def triangle_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Interior angles of each triangle [deg], shape (T, 3), float64."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    out = np.empty((len(p), 3))
    for k in range(3):
        u = p[:, (k + 1) % 3] - p[:, k]
        w = p[:, (k + 2) % 3] - p[:, k]
        cross = np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
        out[:, k] = np.degrees(np.arctan2(cross, np.sum(u * w, axis=1)))
    return out


def mesh_quality(mesh: TissueMesh, tissue_pixel_area: float | None = None) -> dict:
    """Quality figures of a mesh.

    Parameters
    ----------
    mesh : TissueMesh
    tissue_pixel_area : float, optional
        Area of the tissue in the image [m^2] (tissue pixel count * scale^2), for the area error.

    Returns
    -------
    dict
        ``n_vertices``, ``n_triangles``, ``n_edges``, ``n_boundary``, ``n_bodies``,
        ``min_angle``, ``mean_angle`` (of each triangle's smallest angle) [deg],
        ``frac_min_angle_ge_20``, ``n_min_angle_lt_10``, ``area`` [m^2], ``area_error``
        (relative, NaN without ``tissue_pixel_area``), ``min_signed_area`` [m^2] (> 0: all CCW),
        and ``bodies``: a list of per-body dicts with ``body``, ``n_vertices``,
        ``n_triangles``, ``n_boundary``, ``min_angle``, ``mean_angle``, ``frac_min_angle_ge_20``, ``area``.
    """
    v, t = mesh.vertices, mesh.triangles

    def stats(tris: np.ndarray) -> dict:
        if not len(tris):
            return {"min_angle": float("nan"), "mean_angle": float("nan"), "frac_min_angle_ge_20": float("nan"),
                    "n_min_angle_lt_10": 0, "area": 0.0, "min_signed_area": float("nan")}
        mins = triangle_angles(v, tris).min(axis=1)
        area = signed_areas(v, tris)
        return {"min_angle": float(mins.min()), "mean_angle": float(mins.mean()),
                "frac_min_angle_ge_20": float(np.mean(mins >= 20.0)), "n_min_angle_lt_10": int(np.sum(mins < 10.0)),
                "area": float(np.abs(area).sum()), "min_signed_area": float(area.min())}

    q = {"n_vertices": len(v), "n_triangles": len(t), "n_edges": len(mesh.edges),
         "n_boundary": int(mesh.boundary.sum()), "n_bodies": mesh.n_bodies, **stats(t)}
    q["area_error"] = (float("nan") if not tissue_pixel_area
                       else (q["area"] - tissue_pixel_area) / tissue_pixel_area)
    tb = mesh.tri_body
    q["bodies"] = []
    names = mesh.names
    for bi in range(mesh.n_bodies):
        s = stats(t[tb == bi])
        q["bodies"].append({"body": bi, "name": names[bi], "n_vertices": int(np.sum(mesh.body == bi)), "n_triangles": int(np.sum(tb == bi)),
                            "n_boundary": int(np.sum(mesh.boundary & (mesh.body == bi))), **s})
    return q
