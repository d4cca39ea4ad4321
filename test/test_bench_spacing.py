"""tissue-sim bench spacing: the constraint material's dependence on the mesh spacing, against closed forms."""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.bench.spacing import measure
from tissue_sim_ros.cli import main
from tissue_sim_ros.core.config import resolve_config


def test_moduli_mass_and_sag_scale_as_derived():
    k = resolve_config({"method": "xpbd"}).sim
    coarse, fine = measure([0.1, 0.05], mass_per_area=0.0506)
    for row in (coarse, fine):
        # areas: E = 1/2 k_a (A - A0)^2, A0 = h^2/2, isotropic dilation eps -> modulus 2 k_a h^2 exactly on this lattice
        # ((1 + eps)^2 - 1)^2 = 4 eps^2 (1 + eps/2)^2: the probe strain eps = 1e-3 adds a factor 1 + eps
        np.testing.assert_allclose(row["area_modulus_N_per_m"], 2 * k.stiffness_area * row["spacing_m"] ** 2 * (1 + 1e-3), rtol=1e-6)
        # springs: 3/2 k_s in the interior (horizontal k, diagonals k/2); the boundary rows add O(h / size)
        assert 1.5 * k.stiffness_spring < row["spring_modulus_N_per_m"] < 1.5 * k.stiffness_spring * (1 + 4 * row["spacing_m"] / 0.2)
        assert row["static_converged"]
        np.testing.assert_allclose(row["mass_per_area_areal"], 0.0506, rtol=1e-12)
    # Table I's per-particle mass: ~1/h^2 per area (3x from 15 to 45 vertices on the same strip)
    np.testing.assert_allclose(fine["mass_per_area_table_i"] / coarse["mass_per_area_table_i"], 45 / 15)
    assert fine["sag_table_i_m"] > 3.5 * coarse["sag_table_i_m"]  # heavier and softer in area: ~4x
    # the same tissue (areal density), springs alone: the sag moves little with the spacing
    assert abs(fine["sag_springs_only_areal_m"] / coarse["sag_springs_only_areal_m"] - 1) < 0.15


def test_cli_writes_table_csv_and_chart(tmp_path, capsys):
    assert main(["bench", "spacing", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "area_modulus_N_per_m" in out and (tmp_path / "spacing.csv").exists()
    assert (tmp_path / "spacing.png").stat().st_size > 1000
    assert main(["bench", "spacing", "--spacings", "0", "--out", str(tmp_path)]) == 2
