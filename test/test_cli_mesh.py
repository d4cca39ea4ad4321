"""``tissue-sim mesh`` run in-process through tissue_sim_ros.cli.main."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tissue_sim_ros.cli import main
from tissue_sim_ros.core.mesh import load_mesh, mesh_from_image, write_gmsh, write_triangle


def run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(["mesh", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture
def disc_png(tmp_path: Path) -> Path:
    img = np.full((200, 200, 3), 255, dtype=np.uint8)
    cv2.circle(img, (100, 100), 70, (150, 135, 225), -1)
    path = tmp_path / "disc.png"
    cv2.imwrite(str(path), img)
    return path


def table_rows(out: str) -> dict[str, list[str]]:
    rows = {}
    for line in out.splitlines():
        f = line.split()
        if f and (f[0].isdigit() or f[0] == "all") and len(f) >= 9:
            rows[f[0]] = f
    return rows


def test_default_image_writes_mesh_and_picture(tmp_path: Path, capsys):
    rc, out, err = run(capsys, "--out", tmp_path / "m.npz", "--png", tmp_path / "m.png")
    assert rc == 0, err
    rows = table_rows(out)
    assert set(rows) == {"0", "1", "all"}
    assert int(rows["all"][1]) == int(rows["0"][1]) + int(rows["1"][1])
    assert "targets" in out and ": met" in out
    mesh = load_mesh(tmp_path / "m.npz")
    assert mesh.n_bodies == 2 and len(mesh.vertices) == int(rows["all"][1])
    png = cv2.imread(str(tmp_path / "m.png"))
    assert png is not None and png.shape[0] > 300 and png.std() > 10


def test_image_options(disc_png: Path, tmp_path: Path, capsys):
    rc, out, err = run(capsys, disc_png, "--spacing", 0.05, "--scale", 0.005, "--origin", 1, 2,
                       "--color", "150,135,225", "--grade", 1.5, 2.2, 0.05, 0.02, "--out", tmp_path / "d.npz",
                       "--png", tmp_path / "d.png")
    assert rc == 0, err
    mesh = load_mesh(tmp_path / "d.npz")
    # the disc (centre pixel (100, 100), radius 70 px) in the world: centre (1.5, 2.5), radius 0.35 m
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    assert 0.5 * (lo + hi) == pytest.approx([1.5, 2.5], abs=0.005)
    assert 0.5 * (hi - lo) == pytest.approx([0.35, 0.35], abs=0.005)
    same_api = mesh_from_image(disc_png, spacing=0.05, scale=0.005, origin=(1, 2), tissue_color=(150, 135, 225),
                               grading=(1.5, 2.2, 0.05, 0.02))
    assert np.array_equal(mesh.triangles, same_api.triangles)
    assert (tmp_path / "d.png").stat().st_size > 1000
    rc, out, err = run(capsys, disc_png, "--scale", 0.005, "--threshold", 200)
    assert rc == 0 and table_rows(out)["all"][-1].endswith("%")


@pytest.mark.parametrize("kind", ["npz", "node", "ele", "msh"])
def test_mesh_files_are_loaded_and_reported(tmp_path: Path, disc_png: Path, capsys, kind: str):
    mesh = mesh_from_image(disc_png, spacing=0.05, scale=0.005)
    if kind == "npz":
        path = tmp_path / "m.npz"
        mesh.save(path)
    elif kind in ("node", "ele"):
        path = write_triangle(mesh, tmp_path / "m")[0 if kind == "node" else 1]
    else:
        path = write_gmsh(mesh, tmp_path / "m.msh", "4.1")
    rc, out, err = run(capsys, path, "--out", tmp_path / "again.npz", "--png", tmp_path / "again.png")
    assert rc == 0, err
    assert f"mesh file {path}" in out
    assert int(table_rows(out)["all"][2]) == len(mesh.triangles)
    assert np.array_equal(load_mesh(tmp_path / "again.npz").triangles, mesh.triangles)


def bad_inputs(tmp_path: Path, disc_png: Path) -> list[tuple[list, str]]:
    (tmp_path / "text.png").write_text("no pixels here")
    cv2.imwrite(str(tmp_path / "white.png"), np.full((60, 60), 255, np.uint8))
    thin = np.full((100, 200), 255, np.uint8)
    thin[40:44, 10:190] = 0
    cv2.imwrite(str(tmp_path / "thin.png"), thin)
    (tmp_path / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + (9000).to_bytes(4, "big") * 2
                                        + b"\x08\x02\x00\x00\x00")
    (tmp_path / "text.npz").write_text("not a zip archive")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    (tmp_path / "a_dir").mkdir()
    (tmp_path / "dir.npz").mkdir()
    return [
        ([tmp_path / "missing.png"], "missing.png' does not exist"),
        # a directory is named as one (was "does not exist")
        ([tmp_path / "a_dir"], "a_dir' is a directory: expected a file"),
        ([tmp_path / "dir.npz"], "dir.npz' is a directory: expected a file"),
        # no NumPy advice about allow_pickle (a text file was loaded as a pickle)
        ([tmp_path / "text.npz"], "text.npz' is not a valid .npz mesh (not an .npz archive)"),
        ([tmp_path / "other.npz"], "other.npz' is not a valid .npz mesh (no vertices, triangles, edges, boundary, body)"),
        ([tmp_path / "missing.msh"], "missing.msh' does not exist"),
        ([tmp_path / "text.png"], "text.png' is not an image"),
        ([tmp_path / "white.png"], "white.png' is one flat grey level"),
        ([disc_png, "--color", "0,255,0"], "disc.png' has no tissue"),
        ([tmp_path / "thin.png"], "thinner than the spacing"),
        ([disc_png, "--spacing", 0], "--spacing 0.0: expected a number > 0"),
        # refused from the estimate, before any meshing (was a ValueError traceback / minutes of meshing)
        ([disc_png, "--spacing", 1e-300], "would have over 1e308 particles, over the limit max_particles=300000"),
        ([disc_png, "--spacing", 1e-5], "particles, over the limit max_particles=300000"),
        ([disc_png, "--max-particles", 10], "particles, over the limit max_particles=10"),
        ([disc_png, "--max-particles", 0], "max_particles=0: expected a whole number >= 1"),
        ([disc_png, "--scale", -0.001], "--scale -0.001: expected a number > 0"),
        ([disc_png, "--color", "red"], "--color 'red': expected B,G,R"),
        ([disc_png, "--threshold", 300], "threshold 300.0: expected a grey level in [0, 255]"),
        ([tmp_path / "huge.png"], "81000000 pixels: the limit is 50000000"),
        ([disc_png, "--scale", 0.005, "--grade", 0.5, 0.5, 0.1, 0.5], "fine_spacing=0.5"),
    ]


def test_bad_input_exits_2_with_one_line(tmp_path: Path, disc_png: Path, capsys):
    for argv, message in bad_inputs(tmp_path, disc_png):
        rc, out, err = run(capsys, *argv)
        assert rc == 2, (argv, out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("tissue-sim: error: "), (argv, err)
        assert message in lines[0], (argv, err)
        assert "Traceback" not in err and "pickle" not in err and not (tmp_path / "out.npz").exists()


def test_help_explains_the_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["mesh", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for word in ("--spacing", "--scale", "--origin", "--threshold", "--color", "--grade", "--out", "--png",
                 "bottom-left", ".msh"):
        assert word in out


def test_output_names_are_checked_before_anything_is_written(tmp_path: Path, disc_png: Path, capsys):
    """--out must name a .npz (mesh.txt was written as mesh.txt.npz after 'wrote mesh.txt'), --png a .png (a .jpg
    got PNG data): refused in one line before meshing, nothing written; a new directory is made and said."""
    for option, name in (("--out", "mesh.txt"), ("--png", "mesh.jpg")):
        assert main(["mesh", str(disc_png), option, str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and name in err and ("expected a .npz" in err or "expected a .png" in err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["disc.png"]
    out = tmp_path / "new" / "deeper" / "x.npz"
    assert main(["mesh", str(disc_png), "--spacing", "0.1", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"created directory {str(out.parent)!r} for --out" in said and out.exists()
    assert main(["mesh", str(disc_png), "--spacing", "0.1", "--out", str(out)]) == 0  # it exists now: nothing said
    assert "created directory" not in capsys.readouterr().out


def test_a_spacing_below_the_pixel_is_warned_about(tmp_path: Path, capsys):
    """``mesh --spacing 0.0005`` (a quarter of the default 2 mm pixel) ran for minutes without a word about it."""
    img = np.full((30, 30, 3), 255, dtype=np.uint8)
    cv2.circle(img, (15, 15), 10, (150, 135, 225), -1)
    path = tmp_path / "small.png"
    cv2.imwrite(str(path), img)
    rc, out, err = run(capsys, path, "--scale", "0.002", "--spacing", "0.001")
    assert rc == 0, err
    warning = [line for line in err.splitlines() if "warning" in line]
    assert len(warning) == 1 and "--spacing 0.001 m" in warning[0] and "pixel" in warning[0] and "0.002" in warning[0]
    rc, out, err = run(capsys, path, "--scale", "0.002", "--spacing", "0.004")
    assert rc == 0 and "warning" not in err


def test_meshing_reports_its_progress(disc_png: Path):
    """Long meshing shows progress: the meshing reports each stage of each body, in order, up to done."""
    seen: list[tuple[float, str]] = []
    mesh_from_image(disc_png, spacing=0.01, progress=lambda done, stage: seen.append((done, stage)))
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[0] < 0.1 and fractions[-1] == 1.0
    stages = " ".join(stage for _, stage in seen)
    for stage in ("interior points", "boundary recovery", "smoothing", "triangles"):
        assert stage in stages


def test_the_mesh_pictures_legend_shows_the_bodies_as_drawn(tmp_path: Path, monkeypatch):
    """The legend's body swatches had another alpha than the triangles they stand for."""
    import matplotlib.figure
    from matplotlib.collections import PolyCollection

    from tissue_sim_ros.render.mesh import draw_mesh

    figures = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: figures.append(fig))
    mesh = mesh_from_image(Path(__file__).parents[1] / "config" / "tissue.png", spacing=0.05)
    draw_mesh(mesh, tmp_path / "m.png")
    ax = figures[0].axes[0]
    filled = [c for c in ax.collections if isinstance(c, PolyCollection) and len(c.get_facecolors())
              and c.get_facecolors()[:, 3].max() > 0]
    drawn = {tuple(np.round(fc, 3)) for c in filled for fc in c.get_facecolors()}
    swatches = [h for h, label in zip(*ax.get_legend_handles_labels()) if label.startswith("body")]
    assert len(swatches) == len(mesh.names)
    for h in swatches:
        assert tuple(np.round(h.get_facecolor(), 3)) in drawn, (h.get_facecolor(), drawn)
