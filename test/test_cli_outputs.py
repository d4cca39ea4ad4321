"""Every command refuses an output path it cannot write: one line naming the option, exit code 2, before any work.

The check is the dispatcher's (cli/__init__.py, ``check_outputs``), over every output option a command declares,
so it is tested here for every command at once, with each command's ``run`` replaced by one that fails the test:
a refusal that came from the command's own work (after meshing a whole image) would reach it.

An unwritable directory has to really refuse: as root ``chmod`` does not, so the directory is a read-only tmpfs
mount; where mounting is not allowed the tests skip.
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
from pathlib import Path

import pytest

from tissue_sim_ros.cli import COMMANDS, OUTPUT_OPTIONS, main


@pytest.fixture(scope="module")
def read_only_dir(tmp_path_factory):
    """A directory no one can write into, not even root: a tmpfs mounted read-only (unmounted at the end)."""
    path = tmp_path_factory.mktemp("ro")
    try:
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(path)],
                              capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"cannot mount a read-only tmpfs here: {exc}")
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {proc.stderr.strip()}")
    try:
        with pytest.raises(OSError):  # the premise: this directory really refuses
            (path / "probe").write_text("x")
        yield path
    finally:
        subprocess.run(["umount", str(path)], capture_output=True, timeout=30)


def _leaves() -> list[tuple[list[str], str]]:
    out = []
    for name, entry in COMMANDS.items():
        if isinstance(entry, dict):
            out += [([name, sub], module) for sub, (module, _help) in entry.items()]
        else:
            out.append(([name], entry[0]))
    return out


def _required_argv(parser: argparse.ArgumentParser) -> list[str]:
    """The smallest command line the parser accepts: its required options and positionals, each with a value
    of the right type (the first choice, or "1", which parses as a string, an int and a float)."""
    argv: list[str] = []
    for action in parser._actions:
        if not action.required or isinstance(action, argparse._HelpAction):
            continue
        value = str(action.choices[0]) if action.choices else "1"
        argv += [action.option_strings[0], value] if action.option_strings else [value]
    return argv


def _command_cases() -> list[tuple[list[str], str, str]]:
    """(command words, module, output option) for every output option of every command."""
    cases = []
    for words, module in _leaves():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError:  # an optional extra missing from this build: the command is not offered
            continue
        parser = argparse.ArgumentParser()
        mod.add_arguments(parser)
        options = getattr(mod, "OUTPUTS", OUTPUT_OPTIONS)
        for action in parser._actions:
            for option in action.option_strings:
                if option in options:
                    cases.append((words, module, option))
    return cases


CASES = _command_cases()


def test_every_command_that_writes_declares_its_outputs():
    """The commands of the issue, and every benchmark, have an output option the dispatcher checks."""
    covered = {" ".join(words) for words, _module, _option in CASES}
    for words in (["mesh"], ["config"], ["experiment"], ["replay"], ["demo"], ["record"], ["plan"], ["control"],
                  ["fit"], ["tune"], ["bench", "solver"], ["bench", "node"]):
        assert " ".join(words) in covered, words


@pytest.mark.parametrize("words,module,option", CASES, ids=[f"{' '.join(w)} {o}" for w, _m, o in CASES])
def test_an_unwritable_output_is_one_line_and_exit_2_before_any_work(words, module, option, read_only_dir,
                                                                      monkeypatch, capsys):
    mod = importlib.import_module(module)

    def no_work(args):
        raise AssertionError(f"{' '.join(words)} started its work with an unwritable {option}")

    monkeypatch.setattr(mod, "run", no_work)
    parser = argparse.ArgumentParser()
    mod.add_arguments(parser)
    target = Path(read_only_dir) / "sub" / "out.png"
    code = main([*words, *_required_argv(parser), option, str(target)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and option in err[0] and "not writable" in err[0] and "Traceback" not in err[0], err
    assert not (Path(read_only_dir) / "sub").exists()


def test_a_writable_output_passes_the_check(tmp_path, capsys):
    assert main(["config", "--out", str(tmp_path / "new" / "c.yaml")]) == 0
    assert (tmp_path / "new" / "c.yaml").is_file()


def test_mesh_to_a_read_only_folder_refuses_before_meshing(read_only_dir, capsys):
    """The newcomer's command: ``tissue-sim mesh --out ro/m.npz`` printed 31 lines ending in OSError after meshing."""
    code = main(["mesh", "--out", str(Path(read_only_dir) / "m.npz")])
    out = capsys.readouterr()
    assert code == 2
    assert out.out == ""  # no quality table: nothing was meshed
    assert out.err.count("\n") == 1 and "--out" in out.err and "Read-only file system" in out.err
