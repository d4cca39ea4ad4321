"""Image -> mesh and mesh loaders (tissue_sim_ros.core.mesh).

Synthetic shapes are drawn here with OpenCV on small images (1 m across at
0.005 m/px, spacing 0.05 m = 10 px), so their area and topology are known:
pixel area = tissue pixel count * scale^2, holes from the Euler characteristic
(per body V - E + F = 1 - holes).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import (
    Grading,
    TissueMesh,
    estimate_vertices,
    load_mesh,
    mesh_from_image,
    mesh_quality,
    mesh_rectangle,
    tissue_mask,
    triangle_angles,
    write_gmsh,
    write_triangle,
)
from tissue_sim_ros.core.resources import DEFAULT_IMAGE, config_path

SCALE = 0.005  # m/px: a 200 px image is 1 m
SPACING = 0.05  # m: 10 px
TISSUE_BGR = (150, 135, 225)


def blank(h: int = 200, w: int = 200) -> np.ndarray:
    return np.full((h, w, 3), 255, dtype=np.uint8)


def disc() -> np.ndarray:
    img = blank()
    cv2.circle(img, (100, 100), 70, TISSUE_BGR, -1)
    return img


def ring() -> np.ndarray:
    img = disc()
    cv2.circle(img, (100, 100), 30, (255, 255, 255), -1)
    return img


def two_blobs() -> np.ndarray:
    img = blank()
    cv2.ellipse(img, (90, 50), (70, 30), 10, 0, 360, TISSUE_BGR, -1)   # upper (small row = high y)
    cv2.ellipse(img, (110, 150), (60, 35), -15, 0, 360, TISSUE_BGR, -1)
    return img


def strip() -> np.ndarray:
    img = blank(100, 240)
    cv2.rectangle(img, (10, 40), (229, 64), TISSUE_BGR, -1)  # 220 x 25 px = 2.5 spacings thick
    return img


def l_shape() -> np.ndarray:
    img = blank()
    pts = np.array([[20, 20], [70, 20], [70, 130], [180, 130], [180, 180], [20, 180]], dtype=np.int32)
    cv2.fillPoly(img, [pts], TISSUE_BGR)
    return img


def holes(mesh: TissueMesh) -> int:
    """Holes from the Euler characteristic: each body is a disc with holes, V - E + F = 1 - holes."""
    n = 0
    for b in range(mesh.n_bodies):
        v = int(np.sum(mesh.body == b))
        tris = mesh.triangles[mesh.tri_body == b]
        e = {tuple(sorted(p)) for t in tris for p in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        n += 1 - (v - len(e) + len(tris))
    return n


def signed_areas(mesh: TissueMesh) -> np.ndarray:
    p = mesh.vertices[mesh.triangles]
    return 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                  - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))


def boundary_px_error(mesh: TissueMesh, mask: np.ndarray, scale: float, origin=(0.0, 0.0)) -> float:
    """Largest distance [px] from a boundary vertex to the OpenCV contour polyline (through pixel centres)."""
    H = mask.shape[0]
    b = mesh.vertices[mesh.boundary]
    p = np.stack([(b[:, 0] - origin[0]) / scale, H - (b[:, 1] - origin[1]) / scale], axis=1)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    segs = []
    for c in contours:
        q = c[:, 0, :].astype(np.float64) + 0.5
        segs.append(np.stack([q, np.roll(q, -1, axis=0)], axis=1))
    s = np.concatenate(segs)
    a, d = s[:, 0], s[:, 1] - s[:, 0]
    dd = np.maximum(np.sum(d * d, axis=1), 1e-12)
    t = np.clip(np.sum((p[:, None, :] - a) * d, axis=2) / dd, 0, 1)
    dist = np.linalg.norm(p[:, None, :] - (a + t[:, :, None] * d), axis=2).min(axis=1)
    return float(dist.max())


def check_mesh(mesh: TissueMesh, image, scale: float = SCALE, origin=(0.0, 0.0), **kw) -> dict:
    """The issue's targets: CCW, unique edges, quality, area within 2 %, boundary within a pixel."""
    mask = tissue_mask(image, **kw)
    q = mesh_quality(mesh, mask.sum() * scale ** 2)
    assert np.all(signed_areas(mesh) > 0), "every triangle counter-clockwise with positive area"
    assert len(np.unique(mesh.edges, axis=0)) == len(mesh.edges) and np.all(mesh.edges[:, 0] < mesh.edges[:, 1])
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[mesh.triangles.ravel()] = True
    assert used.all(), "no vertex without a triangle"
    assert q["frac_min_angle_ge_20"] >= 0.99, q
    assert q["n_min_angle_lt_10"] == 0, q
    assert abs(q["area_error"]) <= 0.02, q
    assert boundary_px_error(mesh, mask, scale, origin) <= 1.0
    # triangles never span two bodies
    assert np.all(mesh.body[mesh.triangles] == mesh.tri_body[:, None])
    return q


# --------------------------------------------------------------------------- shapes

def test_disc_is_one_body_without_holes():
    img = disc()
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    check_mesh(mesh, img)
    assert mesh.n_bodies == 1 and holes(mesh) == 0
    # the disc's area is pi r^2 with r = 70 px, up to the pixelation of the drawn circle
    assert mesh_quality(mesh)["area"] == pytest.approx(np.pi * (70 * SCALE) ** 2, rel=0.02)


def test_ring_keeps_its_hole():
    img = ring()
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    check_mesh(mesh, img)
    assert mesh.n_bodies == 1 and holes(mesh) == 1
    # no triangle covers the hole's centre (world (0.5, 0.5))
    p = mesh.vertices[mesh.triangles]
    c = np.array([100 * SCALE, (200 - 100) * SCALE])
    inside = []
    for a, b, d in p:
        m = np.array([b - a, d - a]).T
        lam = np.linalg.solve(m, c - a)
        inside.append(lam.min() >= 0 and lam.sum() <= 1)
    assert not any(inside)
    # the hole's boundary vertices are marked: vertices within 35 px of the centre are all boundary
    r = np.linalg.norm(mesh.vertices - c, axis=1)
    assert np.all(mesh.boundary[r < 35 * SCALE]) and np.sum(r < 35 * SCALE) >= 15


def test_two_blobs_are_two_bodies_upper_first():
    img = two_blobs()
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    q = check_mesh(mesh, img)
    assert mesh.n_bodies == 2 and holes(mesh) == 0
    ys = [mesh.vertices[mesh.body == b, 1].mean() for b in range(2)]
    assert ys[0] > ys[1], "body 0 is the upper tissue"
    assert [b["n_triangles"] > 0 for b in q["bodies"]] == [True, True]


def test_thin_strip_meshes_across_its_thickness():
    img = strip()
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    check_mesh(mesh, img)
    assert mesh.n_bodies == 1 and holes(mesh) == 0
    height = np.ptp(mesh.vertices[:, 1])
    assert height == pytest.approx(25 * SCALE, abs=SCALE)


def test_l_shape_area_and_corners():
    img = l_shape()
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    check_mesh(mesh, img)
    # fillPoly includes both end pixels: (70-20+1) x (180-20+1) + (180-70) x (180-130+1)
    exact_px = 51 * 161 + 110 * 51
    assert mesh_quality(mesh)["area"] == pytest.approx(exact_px * SCALE ** 2, rel=0.02)
    # the concave corner is not filled: world point just outside it (px col 100, row 100) is in no triangle
    assert holes(mesh) == 0


def test_noisy_jpeg(tmp_path: Path):
    img = disc().astype(np.float64)
    img += np.random.default_rng(1).normal(0.0, 12.0, img.shape)
    path = tmp_path / "noisy.jpg"
    assert cv2.imwrite(str(path), np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 70])
    mesh = mesh_from_image(path, spacing=SPACING, scale=SCALE)
    check_mesh(mesh, path)
    assert mesh.n_bodies == 1 and holes(mesh) == 0
    assert mesh_quality(mesh)["area"] == pytest.approx(np.pi * (70 * SCALE) ** 2, rel=0.02)


def test_default_image_meets_targets():
    path = config_path(DEFAULT_IMAGE)
    mesh = mesh_from_image(path)  # defaults: spacing 0.05 m, scale 0.002 m/px
    q = check_mesh(mesh, path, scale=0.002)
    assert mesh.n_bodies == 2 and holes(mesh) == 0
    assert 300 <= q["n_vertices"] <= 450, "the paper-sized scene"
    upper, lower = (mesh.vertices[mesh.body == b] for b in range(2))
    assert upper[:, 1].min() > 0.6 and upper[:, 1].max() < 1.0
    assert lower[:, 1].min() > 0.0 and lower[:, 1].max() < 0.42
    assert upper[:, 1].min() - lower[:, 1].max() > 0.2, "a gap for the tool"


def test_default_image_pin_lines_hold_only_the_flat_outer_rows():
    from tissue_sim_ros.core.sim.scene import load_params_file

    params = load_params_file(config_path("tissue_sim.yaml"))
    mesh = mesh_from_image(config_path(DEFAULT_IMAGE), spacing=params["spacing"], scale=params["scale"])
    y = mesh.vertices[:, 1]
    top = y >= params["boundary_y_top"]
    bottom = y <= params["boundary_y_bottom"]
    # the pinned rows are boundary vertices of the right body lying on the flat edges
    assert top.sum() >= 15 and bottom.sum() >= 15
    assert np.all(mesh.boundary[top | bottom])
    assert np.all(mesh.body[top] == 0) and np.all(mesh.body[bottom] == 1)
    assert np.ptp(y[top]) < 0.002 and np.ptp(y[bottom]) < 0.002


def test_finer_spacing_keeps_quality():
    img = ring()
    mesh = mesh_from_image(img, spacing=0.02, scale=SCALE)
    check_mesh(mesh, img)
    coarse = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    assert len(mesh.triangles) > 4 * len(coarse.triangles)


def test_graded_mesh_is_finer_near_the_point():
    img = disc()
    g = Grading(x=0.5, y=0.15, radius=0.05, fine_spacing=0.015)
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE, grading=g)
    check_mesh(mesh, img)
    e = mesh.edges
    mid = 0.5 * (mesh.vertices[e[:, 0]] + mesh.vertices[e[:, 1]])
    length = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    d = np.linalg.norm(mid - [g.x, g.y], axis=1)
    near, far = length[d < g.radius].mean(), length[d > 0.3].mean()
    assert near < 0.5 * far
    assert far == pytest.approx(SPACING, rel=0.2)
    uniform = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    assert len(mesh.triangles) > len(uniform.triangles)


def test_meshing_is_deterministic():
    a = mesh_from_image(two_blobs(), spacing=SPACING, scale=SCALE, grading=(0.5, 0.5, 0.1, 0.02))
    b = mesh_from_image(two_blobs(), spacing=SPACING, scale=SCALE, grading=(0.5, 0.5, 0.1, 0.02))
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)


# --------------------------------------------------------------------------- world frame and segmentation

def test_pixel_to_world_mapping_flips_y():
    # a block of tissue pixels rows [20, 60), cols [30, 130) in a 100 x 200 image
    img = np.full((100, 200), 255, dtype=np.uint8)
    img[20:60, 30:130] = 40
    ox, oy, s = 1.0, -2.0, 0.01
    mesh = mesh_from_image(img, spacing=0.1, scale=s, origin=(ox, oy))
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    # x = ox + col * s, y = oy + (H - row) * s, with the block's pixel edges at cols 30..130, rows 20..60
    assert lo[0] == pytest.approx(ox + 30 * s, abs=0.5 * s)
    assert hi[0] == pytest.approx(ox + 130 * s, abs=0.5 * s)
    assert lo[1] == pytest.approx(oy + (100 - 60) * s, abs=0.5 * s)
    assert hi[1] == pytest.approx(oy + (100 - 20) * s, abs=0.5 * s)
    assert mesh_quality(mesh)["area"] == pytest.approx(40 * 100 * s * s, rel=0.01)


def test_dark_background_and_threshold_and_colour():
    # light tissue on a dark background: the border decides which side is background
    img = np.zeros((200, 200, 3), dtype=np.uint8)
    cv2.circle(img, (100, 100), 60, (200, 200, 200), -1)
    assert tissue_mask(img)[100, 100] and not tissue_mask(img)[5, 5]
    assert tissue_mask(img, threshold=100)[100, 100]
    # a colour picks one of two differently coloured blobs
    two = blank()
    cv2.circle(two, (50, 100), 40, (0, 0, 255), -1)
    cv2.circle(two, (150, 100), 40, (255, 0, 0), -1)
    red = tissue_mask(two, tissue_color=(0, 0, 255))
    assert red[100, 50] and not red[100, 150]
    mesh = mesh_from_image(two, spacing=SPACING, scale=SCALE, tissue_color=(0, 0, 255))
    assert mesh.n_bodies == 1 and mesh.vertices[:, 0].max() < 0.5


def test_mesh_quality_and_angles_on_known_triangles():
    mesh = mesh_rectangle(1.0, 0.5, 0.25)
    ang = triangle_angles(mesh.vertices, mesh.triangles)
    assert np.allclose(np.sort(ang, axis=1), [45.0, 45.0, 90.0])
    q = mesh_quality(mesh, tissue_pixel_area=0.5)
    assert q["area"] == pytest.approx(0.5) and q["area_error"] == pytest.approx(0.0, abs=1e-12)
    assert q["min_angle"] == pytest.approx(45.0) and q["frac_min_angle_ge_20"] == 1.0
    assert q["bodies"][0]["n_triangles"] == len(mesh.triangles)


# --------------------------------------------------------------------------- loaders

@pytest.fixture(scope="module")
def two_body_mesh() -> TissueMesh:
    return mesh_from_image(two_blobs(), spacing=SPACING, scale=SCALE)


def same(a: TissueMesh, b: TissueMesh) -> None:
    assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(a.triangles, b.triangles)
    assert np.array_equal(a.edges, b.edges)
    assert np.array_equal(a.boundary, b.boundary)
    assert np.array_equal(a.body, b.body)


@pytest.mark.parametrize("first_index", [0, 1])
def test_triangle_round_trip(tmp_path: Path, two_body_mesh: TissueMesh, first_index: int):
    node, ele = write_triangle(two_body_mesh, tmp_path / "m", first_index=first_index)
    for p in (node, ele):
        same(two_body_mesh, load_mesh(p))
    (tmp_path / "m.poly").write_text("0 2 0 1\n0 0\n0\n")  # Triangle's "nodes in the .node file"
    same(two_body_mesh, load_mesh(tmp_path / "m.poly"))


def test_triangle_poly_finds_refined_output(tmp_path: Path, two_body_mesh: TissueMesh):
    # `triangle -pq foo.poly` writes foo.1.node / foo.1.ele
    write_triangle(two_body_mesh, tmp_path / "foo.1")
    (tmp_path / "foo.poly").write_text("0 2 0 1\n")
    same(two_body_mesh, load_mesh(tmp_path / "foo.poly"))


def test_triangle_with_attributes_comments_and_clockwise_input(tmp_path: Path):
    (tmp_path / "q.node").write_text("# a unit square\n4 2 1 1\n1 0 0 7.5 1\n2 1 0 7.5 1\n"
                                     "3 1 1 7.5 1\n4 0 1 7.5 1  # last\n")
    (tmp_path / "q.ele").write_text("2 3 1\n1 1 3 2 0.0\n2 1 4 3 0.0\n")  # first triangle clockwise
    mesh = load_mesh(tmp_path / "q.node")
    assert np.all(signed_areas(mesh) > 0)
    assert mesh_quality(mesh)["area"] == pytest.approx(1.0)
    assert mesh.boundary.all() and len(mesh.edges) == 5


@pytest.mark.parametrize("version", ["2.2", "4.1"])
def test_gmsh_round_trip(tmp_path: Path, two_body_mesh: TissueMesh, version: str):
    path = write_gmsh(two_body_mesh, tmp_path / f"m{version}.msh", version=version)
    same(two_body_mesh, load_mesh(path))


def test_gmsh_ignores_other_elements(tmp_path: Path):
    # format 2.2 as Gmsh writes it: a point, two boundary lines, two triangles; node 5 unused
    text = ("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n1\n2 1 \"tissue\"\n$EndPhysicalNames\n"
            "$Nodes\n5\n10 0 0 0\n20 2 0 0\n30 2 1 0\n40 0 1 0\n50 9 9 0\n$EndNodes\n"
            "$Elements\n5\n1 15 2 0 1 10\n2 1 2 0 1 10 20\n3 1 2 0 1 20 30\n"
            "4 2 2 1 1 10 20 30\n5 2 2 1 1 10 30 40\n$EndElements\n")
    (tmp_path / "g.msh").write_text(text)
    mesh = load_mesh(tmp_path / "g.msh")
    assert len(mesh.vertices) == 4 and len(mesh.triangles) == 2
    assert mesh_quality(mesh)["area"] == pytest.approx(2.0)


def test_npz_round_trip(tmp_path: Path, two_body_mesh: TissueMesh):
    two_body_mesh.save(tmp_path / "m.npz")
    same(two_body_mesh, load_mesh(tmp_path / "m.npz"))


# --------------------------------------------------------------------------- bad input

def test_bad_input_missing_file(tmp_path: Path):
    with pytest.raises(InputError, match="nope.png.*does not exist"):
        mesh_from_image(tmp_path / "nope.png")
    with pytest.raises(InputError, match="nope.msh.*does not exist"):
        load_mesh(tmp_path / "nope.msh")


def test_bad_input_not_an_image(tmp_path: Path):
    p = tmp_path / "text.png"
    p.write_text("not an image")
    with pytest.raises(InputError, match="text.png.*not an image.*PNG, JPEG or BMP"):
        mesh_from_image(p)


def test_bad_input_no_tissue(tmp_path: Path):
    with pytest.raises(InputError, match="flat grey level"):
        mesh_from_image(blank())
    noise = np.clip(128 + 20 * np.random.default_rng(0).standard_normal((100, 100)), 0, 255).astype(np.uint8)
    with pytest.raises(InputError, match="no clear tissue"):
        mesh_from_image(noise)
    with pytest.raises(InputError, match="no tissue"):
        mesh_from_image(disc(), tissue_color=(0, 255, 0))
    # only specks smaller than the noise limit
    specks = blank()
    specks[50:52, 50:52] = 0
    specks[10:12, 100:103] = 0
    with pytest.raises(InputError, match="no tissue"):
        mesh_from_image(specks)


def test_bad_input_tissue_thinner_than_spacing():
    img = blank()
    cv2.rectangle(img, (10, 100), (190, 105), TISSUE_BGR, -1)  # 6 px = 0.03 m thick
    with pytest.raises(InputError, match=r"region 0 .*181 x 6 px.*thinner than the spacing 0\.05"):
        mesh_from_image(img, spacing=SPACING, scale=SCALE)
    # a thick body beside it does not hide the thin one
    cv2.circle(img, (100, 40), 30, TISSUE_BGR, -1)
    with pytest.raises(InputError, match="region 1 .*thinner than the spacing"):
        mesh_from_image(img, spacing=SPACING, scale=SCALE)


@pytest.mark.parametrize("kw, what", [({"spacing": 0.0}, "spacing=0.0"), ({"spacing": -0.1}, "spacing=-0.1"),
                                      ({"scale": 0}, "scale=0"), ({"spacing": float("nan")}, "spacing=nan"),
                                      ({"scale": "abc"}, "scale='abc'")])
def test_bad_input_spacing_and_scale(kw: dict, what: str):
    with pytest.raises(InputError, match=f"{what}.*expected a number > 0"):
        mesh_from_image(disc(), **kw)


def test_bad_input_huge_image(tmp_path: Path):
    with pytest.raises(InputError, match="40000 pixels: the limit is 1000"):
        mesh_from_image(disc(), max_pixels=1000)
    # a PNG whose header claims 20000 x 20000 px is refused before decoding
    p = tmp_path / "huge.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\rIHDR" + (20000).to_bytes(4, "big") * 2 + b"\x08\x02\x00\x00\x00")
    with pytest.raises(InputError, match="20000 x 20000 = 400000000 pixels: the limit is 50000000"):
        mesh_from_image(p)


def test_bad_grading():
    with pytest.raises(InputError, match="fine_spacing"):
        mesh_from_image(disc(), spacing=SPACING, scale=SCALE, grading=(0.5, 0.5, 0.1, 0.2))


def test_bad_mesh_files(tmp_path: Path):
    (tmp_path / "a.node").write_text("3 2 0 0\n1 0 0\n2 1 0\n3 0 1\n")
    with pytest.raises(InputError, match="a.node \\+ .*a.ele"):
        load_mesh(tmp_path / "a.node")
    (tmp_path / "a.ele").write_text("1 3 0\n1 1 2 9\n")
    with pytest.raises(InputError, match="node 9"):
        load_mesh(tmp_path / "a.node")
    (tmp_path / "b.msh").write_text("$MeshFormat\n4.1 1 8\n$EndMeshFormat\n$Nodes\n$EndNodes\n$Elements\n$EndElements\n")
    with pytest.raises(InputError, match="binary"):
        load_mesh(tmp_path / "b.msh")
    (tmp_path / "c.msh").write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n2\n1 0 0 0\n2 1 0 0\n$EndNodes\n"
                                    "$Elements\n1\n1 1 2 0 1 1 2\n$EndElements\n")
    with pytest.raises(InputError, match="no 3-node triangles"):
        load_mesh(tmp_path / "c.msh")
    (tmp_path / "d.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match="expected a .npz, Triangle"):
        load_mesh(tmp_path / "d.obj")


# --------------------------------------------------------------------------- irregular shapes

def random_blobs(seed: int) -> np.ndarray:
    """1-3 overlapping wavy blobs (concave corners where they meet), sometimes with a hole."""
    rng = np.random.default_rng(seed)
    img = np.full((300, 300, 3), 255, dtype=np.uint8)
    th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    for _ in range(rng.integers(1, 4)):
        c, r0 = rng.uniform(60, 240, 2), rng.uniform(30, 70)
        r = r0 * (1 + sum(rng.uniform(0, 0.25) * np.sin(m * th + rng.uniform(0, 6)) for m in range(2, 6)))
        cv2.fillPoly(img, [np.stack([c[0] + r * np.cos(th), c[1] + r * np.sin(th)], 1).astype(np.int32)], TISSUE_BGR)
    if rng.random() < 0.5:
        cv2.circle(img, tuple(int(v) for v in rng.uniform(120, 180, 2)), int(rng.uniform(10, 20)), (255, 255, 255), -1)
    return img


@pytest.mark.parametrize("seed", range(6))
def test_irregular_shapes_meet_targets(seed: int):
    img = random_blobs(seed)
    check_mesh(mesh_from_image(img, spacing=0.05, scale=SCALE), img)
    check_mesh(mesh_from_image(img, spacing=0.03, scale=SCALE, grading=(0.75, 0.75, 0.1, 0.01)), img)


def test_hole_smaller_than_the_spacing_is_filled():
    img = disc()
    cv2.circle(img, (100, 100), 3, (255, 255, 255), -1)  # rim ~ 20 px < 3 spacings (30 px)
    mesh = mesh_from_image(img, spacing=SPACING, scale=SCALE)
    assert holes(mesh) == 0
    assert mesh_quality(mesh)["n_min_angle_lt_10"] == 0
    cv2.circle(img, (100, 100), 12, (255, 255, 255), -1)  # rim ~ 75 px: kept
    assert holes(mesh_from_image(img, spacing=SPACING, scale=SCALE)) == 1


def test_mesh_size_estimate_is_close_to_the_mesh() -> None:
    """estimate_vertices: a hex lattice has 2 A / (sqrt(3) h^2) vertices; the boundary adds a few percent."""
    img = str(config_path(DEFAULT_IMAGE))
    area = float(tissue_mask(img).sum()) * 0.002 ** 2
    for h in (0.05, 0.02):
        n = len(mesh_from_image(img, spacing=h).vertices)
        assert 0.85 * n <= estimate_vertices(area, h) <= n, (h, n, estimate_vertices(area, h))
    assert estimate_vertices(1.0, 1e-300) == float("inf")


def test_a_mesh_over_max_particles_is_refused_before_meshing() -> None:
    img = str(config_path(DEFAULT_IMAGE))
    with pytest.raises(InputError, match=r"spacing 0.0001 m \(0.632 m\^2 of tissue\) would have about 7.3e\+07 "
                                         r"particles, over the limit max_particles=300000"):
        mesh_from_image(img, spacing=1e-4)
    with pytest.raises(InputError, match="over 1e308 particles"):
        mesh_from_image(img, spacing=1e-300)
    # the limit is a parameter: the 0.05 m mesh (~320 vertices) is refused under 100, made under 400
    with pytest.raises(InputError, match="about 292 particles, over the limit max_particles=100"):
        mesh_from_image(img, spacing=0.05, max_particles=100)
    assert len(mesh_from_image(img, spacing=0.05, max_particles=400).vertices) == 320
    with pytest.raises(InputError, match="graded to 0.0002 m"):  # a graded mesh counts its fine region
        mesh_from_image(img, spacing=0.05, grading=(0.5, 0.62, 0.3, 0.0002))
    with pytest.raises(InputError, match="max_particles=0: expected a whole number >= 1"):
        mesh_from_image(img, max_particles=0)
    with pytest.raises(InputError, match="strip at spacing 0.0001 m would have about 5e\\+07 particles"):
        mesh_rectangle(1.0, 0.5, 1e-4)
    assert mesh_rectangle(0.1, 0.1, 0.05, max_particles=None).vertices.shape == (9, 2)


def test_max_particles_is_a_scene_parameter() -> None:
    from tissue_sim_ros.core.sim.scene import build_simulation

    with pytest.raises(InputError, match="over the limit max_particles=300000"):
        build_simulation({"spacing": 1e-4})
    with pytest.raises(InputError, match="over the limit max_particles=100"):
        build_simulation({"max_particles": 100})
    with pytest.raises(InputError, match="max_particles"):
        build_simulation({"max_particles": 0})


# --------------------------------------------------------------------------- outline corners

def _has_vertex(mesh: TissueMesh, xy, tol: float = 1e-9) -> bool:
    return bool(np.any(np.hypot(mesh.vertices[:, 0] - xy[0], mesh.vertices[:, 1] - xy[1]) <= tol))


@pytest.mark.parametrize("spacing,grading", [(0.05, None), (0.035, None), (0.08, None), (0.05, (0.4, 0.3, 0.1, 0.02))])
def test_sharp_corners_are_vertices_on_the_pixel_corners(spacing, grading):
    img = l_shape()
    H = img.shape[0]
    mesh = mesh_from_image(img, spacing=spacing, scale=SCALE, grading=grading, corners="sharp")
    check_mesh(mesh, img)
    # fillPoly covers pixels 20..70 x 20..180 and 71..180 x 130..180: the staircase's corners in continuous
    # pixel coordinates (column, row), the concave one included
    for c, r in ((20, 20), (71, 20), (71, 130), (181, 130), (181, 181), (20, 181)):
        assert _has_vertex(mesh, (c * SCALE, (H - r) * SCALE)), (c, r)


def test_sharp_corners_keep_a_straight_face_at_every_spacing_where_smoothing_does_not():
    img = strip()  # pixels 10..229 x 40..64: the bottom face is row edge 65, from column 10 to 230
    H = img.shape[0]
    ends = {"sharp": set(), "smooth": set()}
    for corners in ends:
        for spacing in (0.03, 0.04, 0.05, 0.06):
            mesh = mesh_from_image(img, spacing=spacing, scale=SCALE, corners=corners)
            v = mesh.vertices[mesh.boundary]
            bottom = v[np.abs(v[:, 1] - (H - 65) * SCALE) < 0.5 * SCALE]
            ends[corners].add((round(bottom[:, 0].min() / SCALE, 6), round(bottom[:, 0].max() / SCALE, 6)))
    assert ends["sharp"] == {(10.0, 230.0)}
    assert len(ends["smooth"]) > 1 or ends["smooth"] != {(10.0, 230.0)}  # the smoothed outline cuts them off


def test_curved_outlines_have_no_corners():
    # a disc has no straight runs meeting at an angle: sharp and smooth give the same mesh
    a = mesh_from_image(disc(), spacing=SPACING, scale=SCALE, corners="sharp")
    b = mesh_from_image(disc(), spacing=SPACING, scale=SCALE)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)


def test_default_image_is_meshed_as_before_with_smooth_corners():
    # the paper's scene keeps its mesh: smooth is the default
    from tissue_sim_ros.core.config import SceneConfig

    a = SceneConfig().build_mesh()
    b = mesh_from_image(str(config_path(DEFAULT_IMAGE)), spacing=0.05, scale=0.002, corners="smooth")
    assert np.array_equal(a.vertices, b.vertices)
    assert len(a.vertices) == 320 and len(a.triangles) == 535  # the shipped paper mesh


def test_bad_outline_corners():
    from tissue_sim_ros.core.config import SceneConfig

    with pytest.raises(InputError, match="corners='round'"):
        mesh_from_image(disc(), spacing=SPACING, scale=SCALE, corners="round")
    with pytest.raises(InputError, match="outline_corners='round': expected one of smooth, sharp"):
        SceneConfig(outline_corners="round")
