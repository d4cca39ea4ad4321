"""Flat parameters -> Simulation: the shipped YAML, overrides, method aliases."""
from __future__ import annotations

import pytest

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.sim.scene import build_simulation, load_params_file

SMALL = mesh_rectangle(0.2, 0.1, 0.05)


@pytest.mark.parametrize("method, scheme, iterations, substeps", [
    ("pbd", "gauss_seidel", 30, 1),
    ("xpbd", "gauss_seidel", 30, 1),
    ("xpbd_jacobi", "jacobi", 30, 1),
    ("pbd_jacobi", "jacobi", 30, 1),
    ("xpbd_substep", "gauss_seidel", 1, 30),
])
def test_method_alias_is_not_overridden_by_the_shipped_file(method, scheme, iterations, substeps):
    p = build_simulation({"method": method}, mesh=SMALL).params
    assert (p.scheme, p.iterations, p.substeps) == (scheme, iterations, substeps)


def test_explicit_values_win_over_an_alias():
    p = build_simulation({"method": "xpbd_substep", "substeps": 10}, mesh=SMALL).params
    assert (p.method, p.iterations, p.substeps) == ("xpbd", 1, 10)


def test_bad_parameter_is_named(tmp_path):
    with pytest.raises(InputError, match="iterations"):
        build_simulation({"iterations": 0}, mesh=SMALL)
    bad = tmp_path / "bad.yaml"
    bad.write_text("tissue_sim_node:\n  ros__parameters: [1, 2\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_params_file(bad)
    with pytest.raises(InputError, match="does not exist"):
        load_params_file(tmp_path / "missing.yaml")
