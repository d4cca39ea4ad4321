"""The front door: one resolution of parameters for the library, the CLI and the node."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tissue_sim_ros.core.config import (
    BY_NAME,
    HOME,
    PARAMETERS,
    SIM_NAMES,
    Config,
    closest_name,
    load_params_file,
    parse_assignments,
    resolve_config,
)
from tissue_sim_ros.core.contact.tool import ToolPose
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.core.sim.simulation import Simulation

SMALL = mesh_rectangle(0.2, 0.1, 0.05)


def test_every_parameter_has_one_home_and_a_unit_or_doc() -> None:
    assert len(BY_NAME) == len(PARAMETERS)
    assert set(HOME.values()) <= {"sim", "scene", "tool", "node"}
    for spec in PARAMETERS:
        assert spec.description, spec.name
        assert spec.group in ("scene", "physics", "solver", "contact", "tool", "node")


@pytest.mark.parametrize("overrides, expected", [
    ({"method": "xpbd_substep"}, ("xpbd", "gauss_seidel", 1, 30)),
    ({"method": "xpbd_substep", "substeps": 10}, ("xpbd", "gauss_seidel", 1, 10)),
    ({"method": "xpbd_substep", "iterations": 2, "substeps": 5}, ("xpbd", "gauss_seidel", 2, 5)),
    ({"method": "xpbd_jacobi"}, ("xpbd", "jacobi", 30, 1)),
    ({"method": "pbd_jacobi", "iterations": 12}, ("pbd", "jacobi", 12, 1)),
    ({"method": "xpbd", "scheme": "jacobi"}, ("xpbd", "jacobi", 30, 1)),
])
def test_one_alias_rule(overrides, expected) -> None:
    p = resolve_config(overrides).sim
    assert (p.method, p.scheme, p.iterations, p.substeps) == expected


def test_alias_rule_is_the_same_from_a_file_and_from_overrides(tmp_path) -> None:
    # a copy of the shipped file with only the method changed: the alias decides (the file's 30/1 are defaults)
    shipped = (resolve_config().to_yaml()).replace("method: pbd", "method: xpbd_substep")
    path = tmp_path / "p.yaml"
    path.write_text(shipped)
    from_file = resolve_config(params_file=path).sim
    from_set = resolve_config({"method": "xpbd_substep"}).sim
    assert from_file == from_set and (from_file.substeps, from_file.iterations) == (30, 1)


@pytest.mark.parametrize("where", ["library", "file", "set"])
def test_unknown_name_names_the_closest_known_one(where, tmp_path) -> None:
    with pytest.raises(InputError, match=r"unknown parameter 'iteratons'.*did you mean 'iterations'"):
        if where == "library":
            build_simulation({"iteratons": 5}, mesh=SMALL)
        elif where == "file":
            path = tmp_path / "p.yaml"
            path.write_text("tissue_sim_node:\n  ros__parameters:\n    iteratons: 5\n")
            resolve_config(params_file=path)
        else:
            resolve_config(parse_assignments(["iteratons=5"]), source="--set")
    assert closest_name("contact_modle") == "contact_model"


def test_unknown_method_lists_the_aliases() -> None:
    with pytest.raises(InputError, match="pbd, pbd_jacobi, xpbd, xpbd_jacobi, xpbd_substep"):
        resolve_config({"method": "newton"})


def test_types_are_coerced_and_checked() -> None:
    cfg = resolve_config({"dt": 1, "k_area": 1})
    assert isinstance(cfg.sim.dt, float) and cfg.sim.dt == 1.0
    with pytest.raises(InputError, match="iterations=2.5: expected an integer"):
        resolve_config({"iterations": 2.5})
    with pytest.raises(InputError, match="frame_id"):
        resolve_config({"frame_id": "/world"})


def test_printed_yaml_loads_back_identically(tmp_path) -> None:
    cfg = resolve_config({"method": "xpbd_jacobi", "boundary_y_top": float("nan"), "damping": 0.5,
                          "contact_model": "projection", "stiffness_spring": 1e-5})
    path = tmp_path / "resolved.yaml"
    path.write_text(cfg.to_yaml())
    again = resolve_config(params_file=path)
    assert again.changed(cfg) == []
    assert np.isnan(again.sim.boundary_y_top)


def test_groups_and_replace() -> None:
    cfg = resolve_config()
    assert set(cfg.solver) >= {"method", "scheme", "iterations", "substeps"}
    assert "frame_id" in cfg.group("node") and "dt" in cfg.physics
    new = cfg.replace(iterations=5)
    assert new.sim.iterations == 5 and cfg.sim.iterations == 30 and new.changed(cfg) == ["iterations"]
    with pytest.raises(InputError, match="unknown parameter"):
        cfg.replace(iteratons=5)
    assert set(SIM_NAMES).isdisjoint(cfg.group("node"))


def test_a_directory_is_not_a_parameter_file(tmp_path) -> None:
    with pytest.raises(InputError, match=r"parameter file '.*' is a directory: expected a file"):
        load_params_file(tmp_path)
    with pytest.raises(InputError, match=r"parameter file '.*nope.yaml' does not exist"):
        load_params_file(tmp_path / "nope.yaml")


def test_malformed_file_is_one_readable_line(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("tissue_sim_node:\n  ros__parameters:\n    dt: [0.01\n")
    with pytest.raises(InputError) as err:
        load_params_file(bad)
    assert "\n" not in str(err.value) and "line" in str(err.value)


def test_retune_keeps_state_time_and_tool() -> None:
    sim = Simulation.from_config(resolve_config({"method": "xpbd"}), mesh=SMALL)
    for k in range(3):
        sim.step(ToolPose(0.1, 0.2 - 0.01 * k))
    q, t, steps, pose = sim.state.particle_q.copy(), sim.time, sim.step_count, sim.tool_pose
    sim.retune(sim.config.replace(iterations=7, stiffness_spring=20.0))
    assert sim.params.iterations == 7 and sim.solver.params.iterations == 7
    assert np.array_equal(sim.state.particle_q, q) and (sim.time, sim.step_count, sim.tool_pose) == (t, steps, pose)
    with pytest.raises(InputError, match="dt is read-only"):
        sim.retune(sim.config.replace(dt=0.02))


def test_retuned_run_equals_a_run_built_with_the_new_values() -> None:
    a = Simulation.from_config(resolve_config({"method": "xpbd"}), mesh=SMALL)
    b = Simulation.from_config(resolve_config({"method": "xpbd", "iterations": 5}), mesh=SMALL)
    a.retune(a.config.replace(iterations=5))
    for k in range(5):
        ra, rb = a.step(ToolPose(0.1, 0.15 - 0.01 * k)), b.step(ToolPose(0.1, 0.15 - 0.01 * k))
        assert ra.energy.scene_total == rb.energy.scene_total
    assert np.array_equal(a.state.particle_q, b.state.particle_q)


def test_solver_factory_replaces_swapping_solvers() -> None:
    from functools import partial

    from tissue_sim_ros.core.physics.solvers import Solver

    sim = Simulation.from_config(resolve_config(), mesh=SMALL, solver=partial(Solver, order="stored"))
    assert sim.solver.order == "stored"
    sim.retune(sim.config.replace(iterations=3))
    assert sim.solver.order == "stored" and sim.solver.params.iterations == 3


def test_config_is_picklable() -> None:
    import pickle

    cfg = resolve_config({"method": "xpbd_substep"})
    assert isinstance(pickle.loads(pickle.dumps(cfg)), Config)


def test_config_command_prints_what_the_library_resolves(tmp_path) -> None:
    out = subprocess.run([sys.executable, "-m", "tissue_sim_ros.cli", "config", "--set", "method=xpbd_substep"],
                         capture_output=True, text=True, check=True).stdout
    path = tmp_path / "c.yaml"
    path.write_text(out)
    assert resolve_config(params_file=path).changed(resolve_config({"method": "xpbd_substep"})) == []
    bad = subprocess.run([sys.executable, "-m", "tissue_sim_ros.cli", "config", "--set", "iteratons=3"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "did you mean 'iterations'" in bad.stderr


def test_config_out_creates_its_directory_and_bad_paths_are_one_line(tmp_path, capsys) -> None:
    from tissue_sim_ros.cli import main

    out = tmp_path / "new" / "dir" / "c.yaml"
    assert main(["config", "--out", str(out)]) == 0  # as every --out FILE: the directory is made
    assert resolve_config(params_file=out).changed(resolve_config()) == []
    capsys.readouterr()
    (tmp_path / "afile").write_text("")
    for path, message in [(tmp_path / "afile" / "c.yaml", "afile' is not a directory"),
                          (tmp_path / "new", "is a directory: expected a file name")]:
        assert main(["config", "--out", str(path)]) == 2, path  # was a FileNotFoundError traceback, exit 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and "Traceback" not in err, err
    assert main(["config", "--out", str(tmp_path / "other" / "c.yaml"), "--set", "iteratons=3"]) == 2
    assert not (tmp_path / "other").exists()  # bad input creates nothing


def test_recorded_parameters_are_strict_json_and_read_back() -> None:
    """A bag's tissue_sim.params: unset bounds (NaN) written as null, read back as NaN; older bags' bare NaN too."""
    import json

    from tissue_sim_ros.core.config import params_from_json, params_json

    cfg = resolve_config(overrides={"iterations": 12})
    text = params_json(cfg)
    strict = json.loads(text, parse_constant=lambda name: pytest.fail(f"non-standard constant {name}"))
    assert strict["pin_y_top"] is None and strict["iterations"] == 12
    back = resolve_config(overrides=params_from_json(text))
    assert back.changed(cfg) == []
    old = json.dumps(cfg.flat(), default=str)  # as bags recorded before: NaN
    assert resolve_config(overrides=params_from_json(old)).changed(cfg) == []
    with pytest.raises(InputError, match="not JSON"):
        params_from_json("{")
    with pytest.raises(InputError, match="expected an object"):
        params_from_json("[1]")


def test_a_binary_parameter_file_is_one_line_naming_it(tmp_path, capsys):
    """A PNG given to --params used to end in a raw "'utf-8' codec can't decode byte 0x89"."""
    from tissue_sim_ros.cli import main

    png = tmp_path / "tissue.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    assert main(["config", "--params", str(png)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"tissue-sim: error: parameter file {str(png)!r} is not text (a binary file?): expected "
                           "a parameter YAML such as config/tissue_sim.yaml")
