"""Every ```python block of README.md runs as written: pasted into a file of its own and run in a fresh interpreter.

A newcomer copies these blocks first. One of them used to end on names it never defined, and another
started a worker pool outside `if __name__ == "__main__":`, which dies when run as a script
("the worker exited before it was ready"). Each block runs here as a script, from an empty directory,
with nothing but the installed package.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
TIMEOUT_S = 300  # a block takes a few seconds; the first run of a fresh checkout also compiles the numba kernels


def python_blocks(text: str) -> list[str]:
    """The bodies of the ```python fenced blocks, in order."""
    return re.findall(r"^```python[ \t]*\n(.*?)^```[ \t]*$", text, flags=re.MULTILINE | re.DOTALL)


BLOCKS = python_blocks(README.read_text())


def test_readme_has_python_blocks() -> None:
    # the extraction itself: a README rewritten with another fence style must not pass by running nothing
    assert len(BLOCKS) >= 2, "README.md should show the library in ```python blocks"
    assert README.read_text().count("```python") == len(BLOCKS)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block_runs(index: int, tmp_path: Path) -> None:
    script = tmp_path / f"readme_block_{index}.py"
    script.write_text(BLOCKS[index])
    # an old import path (kept one release with a DeprecationWarning "tissue_sim_ros.... moved to ...") fails it:
    # the README shows only the new layout
    proc = subprocess.run([sys.executable, "-W", "error:tissue_sim_ros:DeprecationWarning", str(script)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, (f"README.md python block {index + 1} failed (exit {proc.returncode}):\n"
                                  f"{BLOCKS[index]}\n--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}")


def test_readme_front_page_tells_a_newcomer_what_holds() -> None:
    """After ``make demo`` ``tissue-sim`` was not found from a plain shell and the README never said why; its
    clone line held a literal placeholder; the node's command was the one that gives no force; the speed-accuracy
    chart was gone; and a test count of an older commit went stale with every commit."""
    text = README.read_text()
    assert "source .venv/bin/activate" in text and ".venv/bin/tissue-sim" in text
    assert "source $(VENV)/bin/activate" in (README.parent / "Makefile").read_text()  # make demo says it too
    assert "<this repository>" not in text
    node_rows = [line for line in text.splitlines() if line.startswith("| `tissue_sim_node")]
    assert node_rows and all("-p contact_model:=projection" in row.split("|")[1] for row in node_rows), node_rows
    assert "](docs/img/accuracy.png)" in text
    assert not re.search(r"\d+ passed", text) and "b267033" not in text
    msg_docs = (README.parent / "msg_docs" / "README.md").read_text()
    running = msg_docs.split("## Running", 1)[1].split("```")[1]
    assert "tissue_sim_node --ros-args --params-file config/tissue_sim.yaml -p contact_model:=projection" in running
