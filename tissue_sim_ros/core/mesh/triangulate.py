"""Image -> mesh (the paper's "Mesh Generation"): the mask's outlines resampled at the (optionally
graded) spacing, with sharp corners kept, a hex lattice inside, constrained Delaunay with the
boundary recovered, and smoothing: :func:`mesh_from_image` and :func:`mesh_from_mask`."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from .geometry import segment_distances
from .image import MAX_PIXELS, tissue_mask
from .types import (
    MAX_PARTICLES,
    Progress,
    TissueMesh,
    _max_particles,
    _positive,
    check_mesh_size,
    estimate_vertices,
    mesh_from_arrays,
)

#: Interior lattice points closer than this many local spacings to the boundary are dropped.
_INTERIOR_CLEARANCE = 0.6


#: Graded spacing grows by this much per unit distance outside the fine disc (slow growth keeps angles good).
_GRADING_SLOPE = 0.3


@dataclass(frozen=True)
class Grading:
    """Finer spacing near a point of interest, growing smoothly to the mesh spacing away from it.

    The local target edge length at world point p is
    ``min(spacing, fine_spacing + 0.3 * max(0, |p - (x, y)| - radius))``.
    """

    x: float
    """Centre of the fine region, world x [m]."""
    y: float
    """Centre of the fine region, world y [m]."""
    radius: float
    """Radius of the disc meshed at ``fine_spacing`` [m]."""
    fine_spacing: float
    """Target edge length inside the disc [m]."""


def _as_grading(grading: Grading | tuple | None, spacing: float) -> Grading | None:
    if grading is None:
        return None
    g = grading if isinstance(grading, Grading) else Grading(*map(float, grading))
    if not all(np.isfinite([g.x, g.y, g.radius, g.fine_spacing])):
        raise InputError(f"grading {g}: expected finite x, y, radius, fine_spacing")
    if g.radius < 0 or not 0 < g.fine_spacing <= spacing:
        raise InputError(f"grading radius={g.radius}, fine_spacing={g.fine_spacing}: expected radius >= 0 "
                         f"and 0 < fine_spacing <= spacing={spacing}")
    return g


def mesh_from_image(image: str | Path | np.ndarray, *, spacing: float = 0.05, scale: float = 0.002,
                    origin: tuple[float, float] = (0.0, 0.0), threshold: float | None = None,
                    tissue_color: tuple[int, int, int] | None = None, color_tolerance: float = 40.0,
                    grading: Grading | tuple[float, float, float, float] | None = None,
                    max_pixels: int = MAX_PIXELS, max_particles: int | None = MAX_PARTICLES,
                    corners: str = "smooth", progress: Progress | None = None) -> TissueMesh:
    """Triangle mesh of the tissue in an image (the paper's "Mesh Generation").

    Parameters
    ----------
    image : path or ndarray
        PNG/JPEG/BMP file, or a grey (H, W) / BGR (H, W, 3) uint8 array.
    spacing : float
        Target edge length [m].
    scale : float
        Metres per pixel [m/px].
    origin : (float, float)
        World position [m] of the image's bottom-left corner.
    threshold, tissue_color, color_tolerance
        How tissue is told from background; see :func:`tissue_mask` (default: Otsu).
    grading : Grading or (x, y, radius, fine_spacing), optional
        Finer spacing near a world point; see :class:`Grading`.
    max_pixels : int
        Larger images are refused.
    max_particles : int or None
        A mesh estimated (from the tissue's area and the spacing, see
        :func:`estimate_vertices`) to have more vertices is refused before any
        meshing is done; None: no limit.
    corners : "smooth" or "sharp"
        "sharp": where two straight runs of the outline meet at CORNER_TURN_DEG or more,
        the pixel corner is a vertex and each run between corners is resampled on its
        own, so a straight face ends at the same place at every spacing; "smooth"
        (default, the paper's meshes): the whole outline is resampled by arc length.
    progress : callable, optional
        Called with (fraction done, stage) as the meshing goes (:data:`Progress`).

    Returns
    -------
    TissueMesh
        World coordinates: image column ``c`` and row ``r`` as continuous pixel
        coordinates (pixel (r, c) covers [c, c+1] x [r, r+1], rows pointing down)
        map to ``x = ox + c*scale``, ``y = oy + (H - r)*scale`` (world y up), so
        the image's bottom-left corner lands at ``origin``. Each 8-connected
        tissue region is one body; bodies are numbered by descending centroid y
        (the upper tissue is body 0), ties by ascending x. Holes stay holes,
        except holes whose rim is shorter than three spacings: too small for
        the mesh to resolve, they are filled.

    Notes
    -----
    Per body: the OpenCV contours (outer + holes, ``RETR_CCOMP``,
    ``CHAIN_APPROX_NONE``) are smoothed by one pixel, moved out from the boundary
    pixels' centres onto the pixel edges, and resampled at the target edge
    length; interior points come from a hexagonal lattice at the same spacing
    (a thinned finer lattice when graded) at least 0.6 spacings from the
    boundary; ``cv2.Subdiv2D`` triangulates; triangles whose centroid lies
    outside the body's polygon are dropped; missing boundary segments are
    recovered by removing encroaching points or splitting the segment; a few
    steps of spring smoothing (Persson-Strang) with re-triangulation move the
    interior points to equalise edges. The boundary points never move.
    """
    spacing, scale = _positive("spacing", spacing), _positive("scale", scale)
    max_particles = _max_particles(max_particles)
    ox, oy = (float(v) for v in origin)
    if not (np.isfinite(ox) and np.isfinite(oy)):
        raise InputError(f"origin {origin!r}: expected two finite numbers [m]")
    g = _as_grading(grading, spacing)
    name = f"image {str(image)!r}" if not isinstance(image, np.ndarray) else "image array"
    mask = tissue_mask(image, threshold=threshold, tissue_color=tissue_color, color_tolerance=color_tolerance,
                       max_pixels=max_pixels, name=name)
    return mesh_from_mask(mask, spacing=spacing, scale=scale, origin=(ox, oy), grading=g, name=name,
                          max_particles=max_particles, corners=corners, progress=progress)


def mesh_from_mask(mask: np.ndarray, *, spacing: float = 0.05, scale: float = 0.002,
                   origin: tuple[float, float] = (0.0, 0.0), grading: Grading | tuple | None = None,
                   name: str = "mask", max_particles: int | None = MAX_PARTICLES,
                   corners: str = "smooth", progress: Progress | None = None) -> TissueMesh:
    """Mesh a boolean tissue mask (H, W); see :func:`mesh_from_image` for the method, world frame, limits and
    ``progress``."""
    import cv2  # noqa: PLC0415

    if corners not in OUTLINE_CORNERS:
        raise InputError(f"corners={corners!r}: expected one of {', '.join(OUTLINE_CORNERS)}")

    spacing, scale = _positive("spacing", spacing), _positive("scale", scale)
    max_particles = _max_particles(max_particles)
    g = _as_grading(grading, spacing)
    mask = np.ascontiguousarray(mask, dtype=bool)
    H = mask.shape[0]
    ox, oy = float(origin[0]), float(origin[1])
    h_px = spacing / scale
    size = _SizeField(h_px, None if g is None else
                      ((g.x - ox) / scale, H - (g.y - oy) / scale, g.radius / scale, g.fine_spacing / scale))
    # refuse a mesh too large to be meant before any work that grows with it
    check_mesh_size(_estimate_mask_vertices(mask, size), max_particles,
                    f"{name} meshed at spacing {spacing:.4g} m ({mask.sum() * scale * scale:.4g} m^2 of tissue"
                    + (f", graded to {g.fine_spacing:.4g} m" if g is not None else "") + ")")

    contours, hierarchy = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InputError(f"{name} has no tissue: expected tissue that differs from the background")
    hier = hierarchy[0]
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]

    bodies = []
    for i, c in enumerate(contours):
        if hier[i][3] != -1:
            continue
        holes = []
        child = hier[i][2]
        while child != -1:
            holes.append(contours[child])
            child = hier[child][0]
        r0, c0 = int(c[0, 0, 1]), int(c[0, 0, 0])
        region = labels == labels[r0, c0]
        bodies.append((c, holes, region))
    # world y of the centroid is -(row); descending y = ascending row
    info = []
    for c, holes, region in bodies:
        rows, cols = np.nonzero(region)
        info.append((rows.mean(), cols.mean()))
    order = sorted(range(len(bodies)), key=lambda k: (round(info[k][0], 6), round(info[k][1], 6)))

    all_v, all_t, all_body = [], [], []
    offset = 0
    # each body's share of the work is its share of the tissue's pixels
    sizes = np.array([float(np.count_nonzero(bodies[k][2])) for k in order])
    starts = np.concatenate([[0.0], np.cumsum(sizes)]) / max(float(sizes.sum()), 1.0)
    for bid, k in enumerate(order):
        c, holes, region = bodies[k]
        rows, cols = np.nonzero(region)
        thickness = 2.0 * float(dist[region].max())
        where = (f"{name}: tissue region {bid} (centroid x={ox + (info[k][1] + 0.5) * scale:.4g} m, "
                 f"y={oy + (H - info[k][0] - 0.5) * scale:.4g} m; {cols.max() - cols.min() + 1} x "
                 f"{rows.max() - rows.min() + 1} px, {len(rows)} px, thickest {thickness * scale:.4g} m)")
        local_h = size.h_min_near(rows, cols) if g is not None else h_px
        if thickness < local_h:
            raise InputError(f"{where} is thinner than the spacing {local_h * scale:.4g} m: expected tissue at "
                             "least one spacing thick (use a smaller --spacing or a larger --scale)")
        # a hole whose rim is shorter than three local spacings cannot be resolved by the mesh: it is filled
        holes = [hc for hc in holes
                 if cv2.arcLength(hc, True) >= 3.0 * float(size(hc[:, 0, :].mean(axis=0) + 0.5)[0])]
        loops = ([_boundary_loop(c, size, outer=True, corners=corners)]
                 + [_boundary_loop(hc, size, outer=False, corners=corners) for hc in holes])
        body_progress = None if progress is None else _body_progress(progress, starts[bid], starts[bid + 1],
                                                                      f"body {bid + 1} of {len(order)}")
        pts, tris = _mesh_body(loops, size, body_progress)
        if len(tris) < 3:
            raise InputError(f"{where} gives only {len(tris)} triangles at spacing {spacing:.4g} m: "
                             "expected at least 3 (use a smaller --spacing)")
        all_v.append(pts)
        all_t.append(tris + offset)
        all_body.append(np.full(len(pts), bid, dtype=np.int32))
        offset += len(pts)
    if progress is not None:
        progress(1.0, "done")
    v_px = np.concatenate(all_v)
    world = np.stack([ox + v_px[:, 0] * scale, oy + (H - v_px[:, 1]) * scale], axis=1)
    # boundary flags come from the topology (edges used by one triangle), as for every TissueMesh
    return mesh_from_arrays(world, np.concatenate(all_t), np.concatenate(all_body))


class _SizeField:
    """Target edge length [px] over the image: uniform, or graded around a point (pixel coordinates)."""

    def __init__(self, h: float, grade: tuple[float, float, float, float] | None) -> None:
        self.h = h
        self.grade = grade
        self.h_min = h if grade is None else min(h, grade[3])

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
        if self.grade is None:
            return np.full(len(p), self.h)
        gx, gy, radius, fine = self.grade
        d = np.hypot(p[:, 0] - gx, p[:, 1] - gy)
        return np.minimum(self.h, fine + _GRADING_SLOPE * np.maximum(0.0, d - radius))

    def h_min_near(self, rows: np.ndarray, cols: np.ndarray) -> float:
        step = max(1, len(rows) // 20000)
        return float(self(np.stack([cols[::step] + 0.5, rows[::step] + 0.5], axis=1)).min())


def _estimate_mask_vertices(mask: np.ndarray, size: _SizeField) -> float:
    """Estimated vertex count of meshing ``mask`` with ``size``: the integral of 2 / (sqrt(3) h^2) over the tissue.

    Uniform: :func:`estimate_vertices` of the tissue's pixel area. Graded: summed
    over tissue pixels (a subsample of at most ~1M, each standing for the pixels it skips).
    """
    n_px = int(np.count_nonzero(mask))
    if size.grade is None:
        return estimate_vertices(n_px, size.h)
    step = max(1, int(np.ceil(np.sqrt(mask.size / 1e6))))
    rows, cols = np.nonzero(mask[::step, ::step])
    if len(rows) == 0:
        return 0.0
    h = size(np.stack([cols * step + 0.5, rows * step + 0.5], axis=1))
    with np.errstate(over="ignore", divide="ignore"):
        n = float(np.sum(2.0 / (np.sqrt(3.0) * h * h))) * n_px / len(rows)
    return n if np.isfinite(n) else float("inf")


#: A corner of the outline is kept as a vertex (``corners="sharp"``) where the outline turns by at least this
#: many degrees between two straight runs (of the 1 px polygon approximation) each at least CORNER_RUN_PX long.
CORNER_TURN_DEG = 60.0


CORNER_RUN_PX = 5.0


#: The outline's corners: "smooth" (every point smoothed and resampled by arc length; the paper scene's meshes)
#: or "sharp" (corners between straight runs stay vertices; each run between two corners resampled on its own).
OUTLINE_CORNERS = ("smooth", "sharp")


def _outline_corners(contour: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sharp corners of a pixel contour: their contour indices (ascending) and positions [px] on the pixel edges.

    A corner is a vertex of the contour's polygon approximation (Douglas-Peucker, 1 px) where the two
    adjacent edges are each at least CORNER_RUN_PX long and the outline turns by at least CORNER_TURN_DEG.
    Each of the two runs is the line fitted (principal axis) through its boundary pixels' centres, two pixels
    trimmed at each end (where an 8-connected contour steps diagonally round a corner), moved out onto the
    pixel edges by ``0.5 * max(|nx|, |ny|)`` as the rest of the loop; the corner is where the two lines meet:
    the corner of the pixel staircase.
    """
    import cv2  # noqa: PLC0415

    none = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    c = contour[:, 0, :]
    n_c = len(c)
    poly = cv2.approxPolyDP(contour, 1.0, True)[:, 0, :]
    n = len(poly)
    if n < 3:
        return none
    at = [np.nonzero((c[:, 0] == v[0]) & (c[:, 1] == v[1]))[0] for v in poly]
    if any(len(h) == 0 for h in at):
        return none
    vidx = np.array([int(h[0]) for h in at])
    poly = poly.astype(np.float64)
    # outward normal of an edge e = (ex, ey) is (ey, -ex) for a polygon of positive shoelace area
    area2 = float(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1]))
    sign = 1.0 if area2 > 0 else -1.0

    def run_line(k: int) -> tuple[np.ndarray, np.ndarray]:
        """Point and unit direction of polygon edge k (vertex k to k+1), on the pixel edges."""
        e = poly[(k + 1) % n] - poly[k]
        i0, i1 = int(vidx[k]), int(vidx[(k + 1) % n])
        inner = np.arange(i0 + 2, (i1 if i1 > i0 else i1 + n_c) - 1) % n_c
        pts = c[inner].astype(np.float64) + 0.5 if len(inner) >= 2 else poly[[k, (k + 1) % n]] + 0.5
        mean = pts.mean(axis=0)
        t = np.linalg.svd(pts - mean)[2][0]
        t = t if float(t @ e) >= 0 else -t
        nrm = sign * np.array([t[1], -t[0]])
        return mean + 0.5 * max(abs(nrm[0]), abs(nrm[1])) * nrm, t

    idx, pos = [], []
    for i in range(n):
        e1, e2 = poly[i] - poly[i - 1], poly[(i + 1) % n] - poly[i]
        l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
        if min(l1, l2) < CORNER_RUN_PX:
            continue
        turn = np.degrees(np.arctan2(e1[0] * e2[1] - e1[1] * e2[0], float(e1 @ e2)))
        if abs(turn) < CORNER_TURN_DEG:
            continue
        (p1, t1), (p2, t2) = run_line(i - 1 if i > 0 else n - 1), run_line(i)
        det = t1[1] * t2[0] - t1[0] * t2[1]  # p1 + s t1 = p2 + u t2, solved for s by Cramer's rule
        if abs(det) < 1e-9:
            continue
        d = p2 - p1
        s_ = (d[1] * t2[0] - d[0] * t2[1]) / det
        idx.append(int(vidx[i]))
        pos.append(p1 + s_ * t1)
    if not idx:
        return none
    order = np.argsort(idx)
    return np.asarray(idx, dtype=np.int64)[order], np.asarray(pos)[order]


def _boundary_loop(contour: np.ndarray, size: _SizeField, outer: bool, corners: str = "smooth") -> np.ndarray:
    """One closed boundary loop [px], resampled at the local spacing, shape (n, 2), float64.

    The contour runs through the centres of the boundary pixels; it is smoothed
    (Gaussian, sigma 1 px) and moved outward onto the pixel edges by
    ``0.5 * max(|nx|, |ny|)`` px (the mean distance from the centre line to the
    pixel staircase), so the polygon's area matches the pixel count. Outer loops
    come out counter-clockwise in pixel coordinates (rows down), holes clockwise,
    i.e. the tissue is always on the same side.

    ``corners="sharp"``: the outline's sharp corners (:func:`_outline_corners`) are vertices at the corners
    of the pixel staircase, and each run between two corners is resampled on its own (its ends fixed), so
    a straight face keeps its ends at every spacing; elsewhere the loop is as with ``"smooth"``.
    """
    cidx, cpos = _outline_corners(contour) if corners == "sharp" else (np.zeros(0, dtype=np.int64), None)
    p = contour[:, 0, :].astype(np.float64) + 0.5  # pixel centres in continuous pixel coordinates
    if len(p) >= 5:
        k = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0  # binomial ~ Gaussian sigma 1 px
        ext = np.concatenate([p[-2:], p, p[:2]])
        p = np.stack([np.convolve(ext[:, 0], k, "valid"), np.convolve(ext[:, 1], k, "valid")], axis=1)
    area2 = np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    if (area2 < 0) == outer:
        p = p[::-1]
        if len(cidx):
            cidx, cpos = (len(p) - 1 - cidx)[::-1], cpos[::-1]
    if len(p) >= 3:
        tangent = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
        tn = np.hypot(tangent[:, 0], tangent[:, 1])
        tn[tn == 0] = 1.0
        tangent /= tn[:, None]
        # with the tissue on the left of the direction of travel (in a y-down frame, area2 > 0 for outer),
        # away-from-tissue is (ty, -tx) rotated accordingly
        normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
        probe = p.mean(axis=0)
        if outer and np.mean(np.sum((p - probe) * normal, axis=1)) < 0:
            normal = -normal
        if not outer and np.mean(np.sum((p - probe) * normal, axis=1)) > 0:
            normal = -normal
        p = p + (0.5 * np.maximum(np.abs(normal[:, 0]), np.abs(normal[:, 1])))[:, None] * normal
    if len(cidx):
        q, fixed = _resample_runs(p, cidx, cpos, size)
    else:
        q, fixed = _resample_loop(p, size), np.zeros(0, dtype=np.int64)
    if len(q) >= 3:
        # chords cut off the bulges of a curved boundary (area ~ h^2 / (12 R) per edge); move the
        # resampled points out along the normal so the polygon keeps the contour's area, by at most
        # 0.4 px so the vertices stay within a pixel of the contour
        def area(x: np.ndarray) -> float:
            return 0.5 * abs(float(np.sum(x[:, 0] * np.roll(x[:, 1], -1) - np.roll(x[:, 0], -1) * x[:, 1])))

        perimeter = float(np.sum(np.hypot(*(np.roll(q, -1, axis=0) - q).T)))
        delta = (area(p) - area(q)) / perimeter * (1.0 if outer else -1.0)
        t = np.roll(q, -1, axis=0) - np.roll(q, 1, axis=0)
        t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
        n = np.stack([t[:, 1], -t[:, 0]], axis=1)
        # orient n away from the tissue: outward for outer loops, into the hole for holes
        if (np.mean(np.sum((q - q.mean(axis=0)) * n, axis=1)) < 0) == outer:
            n = -n
        shift = np.clip(delta, -0.4, 0.4) * n
        shift[fixed] = 0.0  # corners stay on the pixel staircase's corners
        q = q + shift
    return q


def _resample_runs(p: np.ndarray, cidx: np.ndarray, cpos: np.ndarray, size: _SizeField,
                   skip: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Resample a closed loop run by run between its corners; the points and the indices of the corners in them.

    Run k goes from corner k to corner k+1 (cyclically): the corner's position, the loop's points strictly
    between the two corners except ``skip`` points next to each (rounded by the 1 px smoothing), the next
    corner. Each run gets ``max(1, round(length in local spacings))`` equal steps of that length.
    """
    n, m = len(p), len(cidx)
    out, fixed = [], []
    for k in range(m):
        i0, i1 = int(cidx[k]), int(cidx[(k + 1) % m])
        inner = np.arange(i0 + 1 + skip, (i1 if i1 > i0 else i1 + n) - skip) % n
        path = np.concatenate([cpos[k][None], p[inner], cpos[(k + 1) % m][None]])
        seg = np.hypot(*np.diff(path, axis=0).T)
        mid = 0.5 * (path[:-1] + path[1:])
        s = np.concatenate([[0.0], np.cumsum(seg / size(mid))])
        steps = max(1, int(round(s[-1])))
        targets = np.arange(steps) * (s[-1] / steps)  # the run's start, not its end (the next run's start)
        fixed.append(sum(len(o) for o in out))
        out.append(np.stack([np.interp(targets, s, path[:, 0]), np.interp(targets, s, path[:, 1])], axis=1))
    return np.concatenate(out), np.asarray(fixed, dtype=np.int64)


def _resample_loop(p: np.ndarray, size: _SizeField) -> np.ndarray:
    """Resample a closed polyline so consecutive points are about the local target spacing apart."""
    closed = np.concatenate([p, p[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    mid = 0.5 * (closed[:-1] + closed[1:])
    # arc length measured in local spacings: equal steps of it give edges of about size(x)
    s = np.concatenate([[0.0], np.cumsum(seg / size(mid))])
    n = max(3, int(round(s[-1])))
    targets = np.arange(n) * (s[-1] / n)
    return np.stack([np.interp(targets, s, closed[:, 0]), np.interp(targets, s, closed[:, 1])], axis=1)


def _segments(loops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of every boundary segment of closed loops, each (M, 2)."""
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(lp, -1, axis=0) for lp in loops])
    return a, b


class _Polygon:
    """A body's boundary polygon [px] with fast point queries.

    Exact even-odd and segment-distance tests cost O(points x segments); a
    signed-distance raster of the polygon (1 px cells) answers every point
    farther than 2 px from the boundary, and only the rest get the exact test.
    """

    def __init__(self, loops: list[np.ndarray]) -> None:
        import cv2  # noqa: PLC0415

        self.a, self.b = _segments(loops)
        allp = np.concatenate(loops)
        self.lo = np.floor(allp.min(axis=0)) - 3
        shape = (np.ceil(allp.max(axis=0)) - self.lo + 4).astype(int)
        inside = np.zeros((shape[1], shape[0]), dtype=np.uint8)
        shift = 4  # 1/16 px vertex precision in fillPoly
        polys = [np.round((lp - self.lo - 0.5) * (1 << shift)).astype(np.int32) for lp in loops]
        cv2.fillPoly(inside, polys, 1, lineType=cv2.LINE_8, shift=shift)
        d_in = cv2.distanceTransform(inside, cv2.DIST_L2, 5)
        d_out = cv2.distanceTransform(1 - inside, cv2.DIST_L2, 5)
        self.sdf = np.where(inside > 0, d_in, -d_out).astype(np.float64)

    def _raster(self, p: np.ndarray) -> np.ndarray:
        ij = np.floor(p - self.lo).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.sdf.shape[1]) & (ij[:, 1] < self.sdf.shape[0])
        out = np.full(len(p), -1e9)
        out[ok] = self.sdf[ij[ok, 1], ij[ok, 0]]
        return out

    def inside(self, p: np.ndarray) -> np.ndarray:
        """True for points (n, 2) inside the polygon, (n,) bool."""
        s = self._raster(p)
        out = s > 0
        near = np.abs(s) < 2.5
        if near.any():
            out[near] = _inside(p[near], self.a, self.b)
        return out

    def clear_of_boundary(self, p: np.ndarray, clearance: np.ndarray) -> np.ndarray:
        """True for points inside and at least ``clearance`` (n,) [px] from the boundary, (n,) bool."""
        s = self._raster(p)
        out = s > clearance + 2.5
        unsure = (s > -2.5) & ~out
        if unsure.any():
            q = p[unsure]
            out[unsure] = _inside(q, self.a, self.b) & (_distance(q, self.a, self.b) >= clearance[unsure])
        return out


def _inside(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon of points (n, 2) for the polygon with segments a -> b; (n,) bool."""
    px, py = points[:, 0:1], points[:, 1:2]
    ax, ay, bx, by = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    cond = (ay > py) != (by > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = ax + (py - ay) * (bx - ax) / (by - ay)
    return (np.sum(cond & (px < xint), axis=1) % 2).astype(bool)


def _distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points (n, 2) to the nearest segment a -> b; (n,) float64."""
    out = np.full(len(points), np.inf)
    for s in range(0, len(points), 2048):  # chunks bound the (n, M) temporaries
        out[s:s + 2048] = segment_distances(points[s:s + 2048], a, b).min(axis=1)
    return out


def _hex_lattice(lo: np.ndarray, hi: np.ndarray, h: float) -> np.ndarray:
    """Hexagonal lattice points with spacing h covering the box [lo, hi], (n, 2)."""
    dy = h * np.sqrt(3.0) / 2.0
    ys = np.arange(lo[1] + 0.5 * dy, hi[1], dy)
    rows = []
    for j, y in enumerate(ys):
        xs = np.arange(lo[0] + (0.25 + 0.5 * (j % 2)) * h, hi[0], h)
        rows.append(np.stack([xs, np.full(len(xs), y)], axis=1))
    return np.concatenate(rows) if rows else np.zeros((0, 2))


def _delaunay(points: np.ndarray) -> np.ndarray:
    """Delaunay triangles (T, 3) of points (n, 2) by cv2.Subdiv2D, as indices into points."""
    import cv2  # noqa: PLC0415

    lo = np.floor(points.min(axis=0)) - 2
    hi = np.ceil(points.max(axis=0)) + 2
    subdiv = cv2.Subdiv2D((int(lo[0]), int(lo[1]), int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1))
    p32 = np.ascontiguousarray(points, dtype=np.float32)
    subdiv.insert(p32)
    tl = subdiv.getTriangleList().reshape(-1, 3, 2).astype(np.float32)
    # map the float32 corner coordinates back to point indices through a 64-bit key per point
    keys = p32.view(np.uint64).ravel()
    order = np.argsort(keys)
    sk = keys[order]
    q = np.ascontiguousarray(tl).view(np.uint64).reshape(-1, 3)
    pos = np.clip(np.searchsorted(sk, q), 0, len(sk) - 1)
    found = sk[pos] == q
    tris = order[pos]
    return tris[np.all(found, axis=1)].astype(np.int64)


def _body_progress(progress: Progress, start: float, end: float, body: str) -> Progress:
    """A body's own progress (0 to 1) as the whole mesh's (``start`` to ``end``)."""
    return lambda done, stage: progress(start + (end - start) * done, f"{body}: {stage}")


#: The share of a body's meshing time each stage takes (measured on the shipped images, roughly): smoothing,
#: a triangulation per iteration, takes most of it
_STAGES = {"interior points": 0.0, "boundary recovery": 0.1, "smoothing": 0.2, "triangles": 0.9}


def _mesh_body(loops: list[np.ndarray], size: _SizeField,
               progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mesh one body from its boundary loops [px]: points (N, 2), boundary first, and triangles (T, 3)."""
    def report(stage: str, within: float = 0.0) -> None:
        if progress is not None:
            names = list(_STAGES)
            start = _STAGES[stage]
            end = _STAGES[names[names.index(stage) + 1]] if stage != names[-1] else 1.0
            progress(start + (end - start) * within, stage)

    report("interior points")
    poly = _Polygon(loops)
    lo, hi = np.concatenate(loops).min(axis=0), np.concatenate(loops).max(axis=0)
    if size.grade is None:
        interior = _hex_lattice(lo, hi, size.h)
    else:
        # the regular lattice where the spacing is the coarse one; where it is finer, a lattice at the
        # finest spacing thinned with probability (h_min / h)^2 (Persson-Strang, seeded: deterministic),
        # minus points crowding a coarse lattice point; the spring smoothing evens out the rest
        coarse = _hex_lattice(lo, hi, size.h)
        coarse = coarse[size(coarse) >= 0.999 * size.h]
        fine = _hex_lattice(lo, hi, size.h_min)
        h_fine = size(fine)
        keep = (h_fine < 0.999 * size.h) & (np.random.default_rng(0).random(len(fine)) < (size.h_min / h_fine) ** 2)
        fine, h_fine = fine[keep], h_fine[keep]
        if len(coarse) and len(fine):
            near = np.array([np.min(np.hypot(*(coarse - p).T)) for p in fine])
            fine = fine[near >= _INTERIOR_CLEARANCE * h_fine]
        interior = np.concatenate([coarse, fine])
    if len(interior):
        interior = interior[poly.clear_of_boundary(interior, _INTERIOR_CLEARANCE * size(interior))]
    report("boundary recovery")
    loops, interior = _recover_boundary(loops, interior)
    poly = _Polygon(loops)
    iterations = 10 if size.grade is None else 30
    interior = _smooth(loops, interior, poly, size, iterations=iterations,
                       on_iteration=lambda i: report("smoothing", i / iterations))
    loops, interior = _recover_boundary(loops, interior)
    poly = _Polygon(loops)
    report("triangles")
    bnd = np.concatenate(loops)
    pts = np.concatenate([bnd, interior])
    tris = _inner_triangles(pts, poly)
    # drop points no kept triangle uses (e.g. a boundary point cut off by a sliver)
    used = np.zeros(len(pts), dtype=bool)
    used[tris.ravel()] = True
    remap = np.cumsum(used) - 1
    return pts[used], remap[tris]


def _edge_keys(tris: np.ndarray, n: int) -> np.ndarray:
    """Unique undirected edges of triangles as int64 keys i * n + j (i < j)."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    return np.unique(e[:, 0] * n + e[:, 1])


def _inner_triangles(pts: np.ndarray, poly: _Polygon) -> np.ndarray:
    """Delaunay triangles of pts whose centroid is inside the polygon, without slivers."""
    tris = _delaunay(pts)
    if not len(tris):
        return tris
    tris = tris[poly.inside(pts[tris].mean(axis=1))]
    p0, p1, p2 = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    area2 = np.abs((p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0]))
    longest = np.max(np.stack([np.sum((p1 - p0) ** 2, 1), np.sum((p2 - p1) ** 2, 1), np.sum((p0 - p2) ** 2, 1)]), axis=0)
    return tris[area2 > 1e-6 * longest]  # sine of the smallest angle below ~1e-6: a sliver


def _recover_boundary(loops: list[np.ndarray], interior: np.ndarray,
                      max_rounds: int = 8) -> tuple[list[np.ndarray], np.ndarray]:
    """Make every boundary segment an edge of the Delaunay triangulation.

    A segment missing from the triangulation has a point inside its diametral
    circle: drop interior points that encroach on it, and if none do, split the
    segment at its midpoint (which stays on the polygon).
    """
    for _ in range(max_rounds):
        bnd = np.concatenate(loops)
        n_all = len(bnd) + len(interior)
        keys = _edge_keys(_delaunay(np.concatenate([bnd, interior])), n_all)
        starts = np.cumsum([0] + [len(lp) for lp in loops])
        seg_i = np.concatenate([np.arange(len(lp)) + s for lp, s in zip(loops, starts)])
        seg_j = np.concatenate([np.roll(np.arange(len(lp)), -1) + s for lp, s in zip(loops, starts)])
        missing_all = ~np.isin(np.minimum(seg_i, seg_j) * n_all + np.maximum(seg_i, seg_j), keys)
        if not missing_all.any():
            break
        new_loops, drop = [], np.zeros(len(interior), dtype=bool)
        for li, lp in enumerate(loops):
            n = len(lp)
            missing = missing_all[starts[li]:starts[li + 1]]
            if not missing.any():
                new_loops.append(lp)
                continue
            split = np.zeros(n, dtype=bool)
            for m in np.nonzero(missing)[0]:
                pa, pb = lp[m], lp[(m + 1) % n]
                c, r = 0.5 * (pa + pb), 0.5 * np.hypot(*(pb - pa))
                enc = (np.hypot(interior[:, 0] - c[0], interior[:, 1] - c[1]) < r) if len(interior) else None
                if enc is not None and enc.any():
                    drop |= enc
                else:
                    split[m] = True
            out = []
            for m in range(n):
                out.append(lp[m])
                if split[m]:
                    out.append(0.5 * (lp[m] + lp[(m + 1) % n]))
            new_loops.append(np.array(out))
        loops = new_loops
        interior = interior[~drop]
    return loops, interior


def _smooth(loops: list[np.ndarray], interior: np.ndarray, poly: _Polygon, size: _SizeField,
            iterations: int, on_iteration: Callable[[int], None] | None = None) -> np.ndarray:
    """Persson-Strang spring smoothing of the interior points with re-triangulation; the boundary stays fixed.

    Each edge pushes its ends apart when shorter than 1.2x its target length
    (scaled so the edges fill the area); a point that would leave the body or
    come closer than 0.3 local spacings to the boundary keeps its place.
    """
    if not len(interior):
        return interior
    bnd = np.concatenate(loops)
    nb = len(bnd)
    pts = np.concatenate([bnd, interior])
    h_loc = size(interior)
    for it in range(iterations):
        if on_iteration is not None:
            on_iteration(it)
        tris = _inner_triangles(pts, poly)
        if not len(tris):
            break
        keys = _edge_keys(tris, len(pts))
        e0, e1 = keys // len(pts), keys % len(pts)
        vec = pts[e0] - pts[e1]
        L = np.hypot(vec[:, 0], vec[:, 1])
        hb = size(0.5 * (pts[e0] + pts[e1]))
        L0 = hb * 1.2 * np.sqrt(np.sum(L ** 2) / np.sum(hb ** 2))
        F = np.maximum(L0 - L, 0.0)
        fvec = (F / np.maximum(L, 1e-12))[:, None] * vec
        force = np.zeros_like(pts)
        np.add.at(force, e0, fvec)
        np.add.at(force, e1, -fvec)
        move = 0.2 * force[nb:]
        new = pts[nb:] + move
        ok = poly.clear_of_boundary(new, 0.3 * size(new))
        pts[nb:][ok] = new[ok]
        if np.max(np.hypot(move[:, 0], move[:, 1]) / h_loc) < 1e-3:
            break
    return pts[nb:].copy()
