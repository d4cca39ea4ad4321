"""Every ``tissue-sim`` command's ``--help`` works and reads as plain text (no Sphinx markup from the docstrings)."""
from __future__ import annotations

import re

import pytest

from tissue_sim_ros.cli import COMMANDS, main, plain_text

#: a Sphinx cross-reference (``:mod:`x` ``, ``:py:func:`x` ``...), a literal (double backticks) or strong emphasis
MARKUP = re.compile(r":(?:py:)?[a-z]+:`|``|(?<![\w*])\*\*\S")


def _commands() -> list[list[str]]:
    argvs: list[list[str]] = [[]]
    for name, entry in COMMANDS.items():
        argvs.append([name])
        if isinstance(entry, dict):
            argvs += [[name, sub] for sub in entry]
    return argvs


@pytest.mark.parametrize("argv", _commands(), ids=lambda argv: " ".join(argv) or "tissue-sim")
def test_help_exits_0_as_plain_text(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0, out
    assert out.startswith(f"usage: tissue-sim {' '.join(argv)}".rstrip()), out[:200]
    assert "not available in this build" not in out  # the command's module imported: its own help is shown
    markup = sorted({m.group() for m in MARKUP.finditer(out)})
    assert not markup, f"tissue-sim {' '.join(argv)} --help shows markup {markup}:\n" + "\n".join(
        line for line in out.splitlines() if MARKUP.search(line))


def test_plain_text_reads_the_markup_as_the_docs_show_it() -> None:
    assert plain_text("exact (Newton, :mod:`~tissue_sim_ros.bench.reference`)") == \
        "exact (Newton, tissue_sim_ros.bench.reference)"  # a module by its whole name: no link to follow
    assert plain_text(":func:`~tissue_sim_ros.core.config.resolve_config`") == "resolve_config()"
    assert plain_text(":class:`~a.b.Solver` and :py:meth:`Pool.run`") == "Solver and Pool.run()"
    assert plain_text(":func:`the reader <a.b.read>`") == "the reader"
    assert plain_text("``--live`` plans on a ``tissue_sim_node``") == "--live plans on a tissue_sim_node"
    assert plain_text("* **ours**: x**2 stays") == "* ours: x**2 stays"


def test_no_help_text_quotes_an_issue_number(capsys):
    """``control --help`` quoted "(issue 31)": a number from the tracker means nothing to a user."""
    import re

    from tissue_sim_ros.cli import COMMANDS, main

    for name, entry in COMMANDS.items():
        for words in ([[name, sub] for sub in entry] if isinstance(entry, dict) else [[name]]):
            with pytest.raises(SystemExit):
                main([*words, "--help"])
            text = capsys.readouterr().out
            assert not re.search(r"\bissues? \d+", text), (words, re.search(r".{40}\bissues? \d+.{20}", text))


def test_control_timing_help_gives_the_candidates_it_runs(capsys):
    """``control --timing`` said 4 to 64 candidates and timed 5 to 65 (each replan also rolls out holding still)."""
    import math

    from tissue_sim_ros.cli import control as cli_control
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.core.plan.control import ControlSettings

    with pytest.raises(SystemExit):
        main(["control", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    counts = []
    for n in (cli_control.TIMING_COUNTS[0], cli_control.TIMING_COUNTS[-1]):  # the grid replan_timing builds
        n_ang = 2 ** math.ceil(math.log2(n) / 2)
        counts.append(ControlSettings(gains=tuple(range(1, max(1, n // n_ang) + 1)),
                                      angles_deg=tuple(range(n_ang)), pull_speeds=(0.02,)).n_candidates)
    assert f"candidates ({counts[0]} to {counts[1]}:" in text, text
