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
