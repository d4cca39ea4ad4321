"""``tissue-sim mesh``: mesh a tissue image (or load a mesh file), report its quality, write .npz and a picture."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..core.errors import InputError, make_parent, output_file
from ..core.mesh import (
    MAX_PARTICLES,
    MESH_SUFFIXES,
    Grading,
    load_meshes,
    mesh_from_mask,
    mesh_quality,
    read_image,
    spacing_warning,
    tissue_mask,
)

HELP = "mesh a tissue image (or load a mesh file), report quality, write .npz and a picture"
DESCRIPTION = """\
Mesh a tissue image the way the simulation does (the paper's "Mesh Generation"):
tissue is what differs from the background (Otsu's threshold by default, or
--threshold / --color), each connected region is one body, holes stay holes.
Prints minimum/mean angle, the share of triangles with all angles >= 20 degrees,
area and its error against the tissue's pixel area, per body and in total.

IMAGE may also be a mesh file (.npz, Triangle .node/.ele/.poly, Gmsh .msh 2.2/4.1):
it is loaded and reported. Several mesh files make one scene: their vertices
and triangles in the order given, each body named after its file (Bottom.1.node
-> "Bottom"; a file of several bodies -> "name[0]", "name[1]", ...); the names
are saved in the .npz and label every plot and summary. Without IMAGE the
shipped default image is meshed (its regions named by position).

World frame: the image's bottom-left corner is at --origin; x = ox + col*scale,
y = oy + (H - row)*scale (rows point down, world y up).

examples:
  tissue-sim mesh --out mesh.npz --png mesh.png
  tissue-sim mesh tissue.jpg --spacing 0.02 --scale 0.001 --color 150,135,225
  tissue-sim mesh --grade 0.5 0.62 0.05 0.015 --png graded.png
  tissue-sim mesh Bottom.1.node Upper.1.node --out scene.npz --png scene.png
"""

#: the mesh quality targets: >= 99 % of triangles with min angle >= 20 deg, none below 10, area within 2 %
TARGET_FRAC_20 = 0.99
TARGET_MIN_ANGLE = 10.0
TARGET_AREA_ERROR = 0.02


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("image", nargs="*", default=[],
                        help="tissue image (PNG/JPEG/BMP), or one or more mesh files combined into one scene; "
                             "default: the shipped tissue.png")
    parser.add_argument("--spacing", type=float, default=0.05, metavar="M", help="target edge length [m] (default 0.05)")
    parser.add_argument("--scale", type=float, default=0.002, metavar="M_PER_PX",
                        help="metres per pixel (default 0.002: a 500 px image is 1 m)")
    parser.add_argument("--origin", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"),
                        help="world position of the image's bottom-left corner [m] (default 0 0)")
    parser.add_argument("--threshold", type=float, default=None, metavar="T",
                        help="grey level [0, 255] separating tissue from background (default: Otsu)")
    parser.add_argument("--color", default=None, metavar="B,G,R",
                        help="tissue colour; pixels within --tolerance of it in every channel are tissue")
    parser.add_argument("--tolerance", type=float, default=40.0, help="colour tolerance per channel (default 40)")
    parser.add_argument("--grade", type=float, nargs=4, default=None, metavar=("X", "Y", "R", "FINE"),
                        help="finer spacing FINE [m] within R [m] of (X, Y), growing smoothly to --spacing")
    parser.add_argument("--max-particles", type=int, default=MAX_PARTICLES, metavar="N",
                        help=f"refuse a mesh estimated (tissue area, spacing) to have more vertices (default "
                             f"{MAX_PARTICLES}; the max_particles parameter)")
    parser.add_argument("--out", type=Path, default=None, metavar="MESH.npz", help="write the mesh (.npz)")
    parser.add_argument("--png", type=Path, default=None, metavar="MESH.png",
                        help="write a picture of the mesh over the image")


def _parse_color(text: str | None) -> tuple[int, int, int] | None:
    if text is None:
        return None
    try:
        bgr = tuple(int(v) for v in text.split(","))
    except ValueError:
        bgr = ()
    if len(bgr) != 3 or not all(0 <= v <= 255 for v in bgr):
        raise InputError(f"--color {text!r}: expected B,G,R with three integers in [0, 255], e.g. 150,135,225")
    return bgr  # type: ignore[return-value]


def run(args: argparse.Namespace) -> int:
    from ..core.resources import DEFAULT_IMAGE, config_path  # noqa: PLC0415

    sources = [Path(p) for p in args.image] if args.image else [config_path(DEFAULT_IMAGE)]
    source = sources[0]
    if len(sources) > 1:
        not_mesh = [str(p) for p in sources if p.suffix.lower() not in MESH_SUFFIXES]
        if not_mesh:
            raise InputError(f"{not_mesh[0]!r}: several inputs must all be mesh files "
                             f"({', '.join(MESH_SUFFIXES)}); mesh an image on its own")
    for name in ("spacing", "scale"):
        v = getattr(args, name)
        if not np.isfinite(v) or v <= 0:
            raise InputError(f"--{name} {v}: expected a number > 0")
    # the output names are checked before any work: a wrong suffix would be written anyway (mesh.txt as
    # mesh.txt.npz, JPEG-named PNG data)
    out = output_file(args.out, "--out", suffixes=(".npz",)) if args.out is not None else None
    png = output_file(args.png, "--png", suffixes=(".png",)) if args.png is not None else None
    image, pixel_area, grading = None, None, None
    t0 = time.perf_counter()
    if source.suffix.lower() in MESH_SUFFIXES:
        mesh = load_meshes(sources)
        what = f"mesh file{'s' if len(sources) > 1 else ''} {', '.join(str(p) for p in sources)}"
    else:
        color = _parse_color(args.color)
        grading = Grading(*args.grade) if args.grade is not None else None
        image = read_image(source)
        name = f"image {str(source)!r}"
        mask = tissue_mask(image, threshold=args.threshold, tissue_color=color, color_tolerance=args.tolerance,
                           name=name)
        warnings = [w for w in (spacing_warning(fine, args.scale, option) for fine, option in
                                ((args.spacing, "--spacing"),
                                 *(((grading.fine_spacing, "--grade FINE"),) if grading else ()))) if w]
        # a bar only once meshing has taken a few seconds: a fine spacing takes minutes with nothing shown
        with tqdm(total=100, desc="meshing", unit="%", delay=2.0, leave=False,
                  bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed} elapsed, {remaining} left{postfix}") as bar:
            def progress(done: float, stage: str) -> None:
                while warnings:  # said once the mesh's size is accepted: a refused one gets its one error line
                    print(f"tissue-sim: warning: {warnings.pop(0)}", file=sys.stderr)
                bar.update(round(100 * done) - bar.n)
                bar.set_postfix_str(stage, refresh=False)

            mesh = mesh_from_mask(mask, spacing=args.spacing, scale=args.scale, origin=tuple(args.origin),
                                  grading=grading, name=name, max_particles=args.max_particles, progress=progress)
        pixel_area = float(mask.sum()) * args.scale ** 2
        what = (f"image {source} ({image.shape[1]} x {image.shape[0]} px at {args.scale:g} m/px, "
                f"spacing {args.spacing:g} m{', graded' if grading else ''})")
    elapsed = time.perf_counter() - t0
    q = mesh_quality(mesh, pixel_area)
    print(f"{what}: {q['n_bodies']} bodies, {q['n_vertices']} vertices, {q['n_triangles']} triangles, "
          f"{q['n_edges']} edges in {elapsed:.3f} s")
    print(format_quality(q))
    ok = (q["frac_min_angle_ge_20"] >= TARGET_FRAC_20 and q["n_min_angle_lt_10"] == 0
          and (pixel_area is None or abs(q["area_error"]) <= TARGET_AREA_ERROR))
    print(f"targets (>= {TARGET_FRAC_20:.0%} of triangles with min angle >= 20 deg, none < {TARGET_MIN_ANGLE:g} deg"
          + (f", area within {TARGET_AREA_ERROR:.0%}" if pixel_area is not None else "") + f"): {'met' if ok else 'NOT met'}")
    if out is not None:
        make_parent(out, "--out")
        mesh.save(out)
        print(f"wrote {out}")
    if png is not None:
        make_parent(png, "--png")
        from ..render.mesh import draw_mesh  # noqa: PLC0415  (matplotlib only when a picture is asked for)

        draw_mesh(mesh, png, image=image, scale=args.scale, origin=tuple(args.origin), grading=grading,
                  title=f"{source.name}: {q['n_vertices']} vertices, {q['n_triangles']} triangles, "
                        f"min angle {q['min_angle']:.1f} deg")
        print(f"wrote {png}")
    return 0


def format_quality(q: dict) -> str:
    """The quality table of :func:`~tissue_sim_ros.core.mesh.mesh_quality`: one row per body and a total."""
    head = (f"{'body':>5} {'verts':>6} {'tris':>6} {'bnd':>5} {'min ang':>8} {'mean min':>9} "
            f"{'>=20deg':>8} {'<10deg':>7} {'area m^2':>10} {'area err':>9}")
    rows = [head, "-" * len(head)]

    def row(label: str, d: dict, err: float) -> str:
        e = "" if not np.isfinite(err) else f"{100 * err:+.2f}%"
        return (f"{label:>5} {d['n_vertices']:>6} {d['n_triangles']:>6} {d['n_boundary']:>5} {d['min_angle']:>8.2f} "
                f"{d['mean_angle']:>9.2f} {100 * d['frac_min_angle_ge_20']:>7.2f}% {d['n_min_angle_lt_10']:>7} "
                f"{d['area']:>10.5f} {e:>9}")

    rows += [row(str(b["body"]), b, float("nan")) for b in q["bodies"]]
    rows.append(row("all", q, q["area_error"]))
    if any("name" in b for b in q["bodies"]):
        rows.append("bodies: " + ", ".join(f"{b['body']} = {b['name']}" for b in q["bodies"] if "name" in b))
    return "\n".join(rows)
