"""tissue-sim tune: a --quick run writes a parameter file the simulation loads, and refuses impossible asks."""
from __future__ import annotations

import csv
import math
from pathlib import Path

from tissue_sim_ros.cli import main
from tissue_sim_ros.core.sim.scene import build_simulation, load_params_file


def test_tune_quick_writes_loadable_parameters(tmp_path: Path) -> None:
    out = tmp_path / "params.yaml"
    table = tmp_path / "tune.csv"
    assert main(["tune", "--quick", "--tolerance", "3", "--budget-ms", "50", "--out", str(out), "--csv", str(table)]) == 0
    values = load_params_file(out)
    assert values["method"] in ("pbd", "xpbd") and values["iterations"] >= 1 and values["spacing"] in (0.1, 0.05)
    with open(table) as f:
        rows = list(csv.DictReader(f))
    assert all(math.isfinite(float(r["error"])) and float(r["ms_per_step"]) > 0 for r in rows)
    # the chosen setting is the fastest measured one within tolerance and budget
    ok = [r for r in rows if float(r["error"]) <= 3 and float(r["ms_per_step"]) <= 50]
    best = min(ok, key=lambda r: float(r["ms_per_step"]))
    assert float(best["spacing"]) == values["spacing"] and int(best["iterations"]) == values["iterations"]
    sim = build_simulation(values)
    assert sim.params.method == values["method"]


def test_tune_impossible_tolerance_returns_1(tmp_path: Path, capsys) -> None:
    out = tmp_path / "params.yaml"
    assert main(["tune", "--quick", "--tolerance", "1e-9", "--budget-ms", "50", "--out", str(out)]) == 1
    assert not out.exists()
    assert f"{out} not written (exit 1)" in capsys.readouterr().out


def test_tune_help_documents_its_exit_status(capsys) -> None:
    """Exit 1 when no setting qualifies was documented only for --verify."""
    import pytest

    with pytest.raises(SystemExit):
        main(["tune", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Exit status: 0 when a setting meets the tolerance within the budget" in text
    assert "1 when none does (nothing is written" in text and "2 on bad input" in text
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    assert "exit 1 (nothing written) when no setting meets it within the budget" in readme


def test_tune_bad_input_exits_2() -> None:
    assert main(["tune", "--tolerance", "0", "--budget-ms", "5"]) == 2
    assert main(["tune", "--tolerance", "0.1", "--budget-ms", "nan"]) == 2
    assert main(["tune", "--tolerance", "0.1", "--budget-ms", "5", "--spacings", "a,b"]) == 2
