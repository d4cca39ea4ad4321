"""The shipped scenes: the real-size liver scene builds from its parameter file alone and runs."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.cli import main
from tissue_sim_ros.core.resources import find_data_file, scene_names, scene_params_file
from tissue_sim_ros.core.sim.scene import build_simulation, load_params_file
from tissue_sim_ros.core.timing import trajectories as tr
from tissue_sim_ros.experiments import paper


def test_scene_names_and_files():
    assert {"paper", "liver_probe"} <= set(scene_names())
    assert scene_params_file("paper").name == "tissue_sim.yaml"
    assert scene_params_file("liver_probe").name == "liver_probe.yaml"
    assert set(tr.SCENE_EXPERIMENTS) == set(scene_names())  # every shipped scene has its experiments


def test_unknown_scene_is_input_error():
    from tissue_sim_ros.core.errors import InputError

    with pytest.raises(InputError, match="nowhere"):
        scene_params_file("nowhere")
    with pytest.raises(InputError, match="nowhere"):
        tr.scene_experiments("nowhere")


@pytest.fixture(scope="module")
def liver():
    return build_simulation(load_params_file(scene_params_file("liver_probe")))


def test_liver_scene_is_real_tissue_at_real_size(liver):
    p = liver.params
    assert p.material == "neo_hookean" and p.method == "ipc" and p.contact_model == "barrier" and p.substeps == 1
    assert 1e3 <= p.young_modulus <= 1e4  # a few kPa (healthy liver, see the YAML's references)
    assert 1000 <= p.density <= 1100
    q0 = liver.model.particle_q0
    size = q0.max(axis=0) - q0.min(axis=0)
    assert 0.02 < size[0] < 0.1 and 0.01 < size[1] < 0.05  # a few centimetres
    assert liver.tool.kind == "capsule" and 1e-3 <= 2 * liver.tool.radius <= 1e-2  # a millimetre-scale instrument
    # lumped mass: the total is density x thickness x the mesh's rest area (each triangle's third to each corner)
    t = liver.model.tri_indices
    e1, e2 = q0[t[:, 1]] - q0[t[:, 0]], q0[t[:, 2]] - q0[t[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    assert liver.model.particle_mass.sum() == pytest.approx(p.density * p.thickness * area, rel=1e-9)
    # the support pins the bottom face only: a straight row at y = 3.8 mm from corner to corner (x = 10 to
    # 70.2 mm, the image's pixel corners, kept by outline_corners: sharp), nothing of the sides
    pinned = liver.model.particle_pinned
    assert pinned.any() and np.all(q0[pinned, 1] <= p.boundary_y_bottom)
    assert np.allclose(q0[pinned, 1], 0.0038, atol=2e-5)
    assert q0[pinned, 0].min() == pytest.approx(0.010, abs=1e-9) and q0[pinned, 0].max() == pytest.approx(0.0702, abs=1e-9)


def test_scene_image_found_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    values = load_params_file(scene_params_file("liver_probe"))
    assert find_data_file(values["image"]).is_file()
    assert not find_data_file("no/such/file.png").is_file()  # left as given, for the loader's own message


def test_liver_experiment_a_runs_and_touches(tmp_path, liver):
    # a short run from a start moved 1 mm above the dome's top: the instrument reaches the tissue within 60 steps
    sc = tr.LIVER_PROBE
    top = liver.model.particle_q0[:, 1].max()
    near = tr.SceneExperiments((0.035, top + liver.tool.radius + 1e-3), -90.0, 1e-4, 60, (0, 60), *(
        sc.b_target, sc.b_distance, sc.b_speed, sc.b_angles_deg, sc.b_tool))
    res = paper.experiment_a(tmp_path, params=load_params_file(scene_params_file("liver_probe")), scene=near,
                             progress=False)
    run = res.rollouts["a"]
    assert res.summary["energy finite"] and res.summary["diverged steps"] == 0
    assert run.in_contact.any()
    assert all(f.is_file() for f in res.files)


def test_cli_scene_choice(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["experiment", "a", "--scene", "nowhere", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "liver_probe" in capsys.readouterr().err  # the usage line names the choices
