"""The folders are the architecture: what each layer and each core package may import.

Arrows point down only::

    cli -> tune -> experiments / bench -> ros -> envs -> render -> core

and inside the core, from the bottom up::

    errors, resources, series -> mesh -> contact -> timing -> physics -> config, health -> sim -> plan, fit

A module may import its own package and anything below it, never above. Every import
counts, including those inside functions (a lazy import is still an arrow); only imports
under ``if TYPE_CHECKING:`` are exempt, since they never run. The core also never
imports ROS, so it runs in a notebook, a planner's loop or a test without a ROS graph.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "tissue_sim_ros"
CORE = PACKAGE / "core"
ROS_MODULES = ("rclpy", "std_msgs", "geometry_msgs", "sensor_msgs", "visualization_msgs", "diagnostic_msgs",
               "std_srvs", "nav_msgs", "rosgraph_msgs", "builtin_interfaces", "tf2_msgs", "rcl_interfaces")

#: the package's layers, bottom (0) to top; a module imports only its own layer or lower ones
LAYERS = {"core": 0, "render": 1, "envs": 2, "ros": 3, "experiments": 4, "bench": 5, "tune": 6, "cli": 7}
#: the core's packages, bottom (0) to top
CORE_RANKS = {"errors": 0, "resources": 0, "series": 0, "mesh": 1, "contact": 2, "timing": 3, "physics": 4,
              "config": 5, "health": 5, "sim": 6, "plan": 7, "fit": 7}
#: modules outside any layer: the package's own __init__ and the aliases of moved modules (they import anything)
UNLAYERED = {"tissue_sim_ros", "tissue_sim_ros._moved"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import of the package that can run (not under TYPE_CHECKING).

    ``from X import name`` counts as an import of ``X.name`` when that is a module of the package.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skipped.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    name = _module_name(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if not module.startswith("tissue_sim_ros"):
                continue
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                found.append((node.lineno, sub if _is_module(sub) else module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("tissue_sim_ros")]
    return found


def _is_module(dotted: str) -> bool:
    path = PACKAGE.parent.joinpath(*dotted.split("."))
    return path.with_suffix(".py").exists() or (path / "__init__.py").exists()


def _sources() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def _layer(module: str) -> tuple[int, int] | None:
    """(layer, rank inside the core) of a module; None for one outside the layers."""
    if module in UNLAYERED:
        return None
    parts = module.split(".")
    if len(parts) < 2 or parts[1] == "config":  # tissue_sim_ros.config: the shipped YAML as package data
        return None
    layer = LAYERS[parts[1]]
    if parts[1] != "core":
        return layer, 0
    if len(parts) == 2:  # tissue_sim_ros.core itself: re-exports the entry points (lazily)
        return None
    return layer, CORE_RANKS[parts[2]]


def test_every_module_has_a_layer():
    unknown = [str(p.relative_to(PACKAGE)) for p in _sources()
               if _module_name(p) not in UNLAYERED and _module_name(p).split(".")[1] not in {*LAYERS, "config"}]
    unknown += [str(p.relative_to(PACKAGE)) for p in (CORE).rglob("*.py")
                if len(_module_name(p).split(".")) > 2 and _module_name(p).split(".")[2] not in CORE_RANKS]
    assert not unknown, f"modules outside every layer (add them to LAYERS/CORE_RANKS or move them): {unknown}"


def test_imports_point_down_only():
    """No module imports a layer above its own, nor a core package above its own."""
    offenders = []
    for path in _sources():
        mine = _layer(_module_name(path))
        if mine is None:
            continue
        for line, target in _runtime_imports(path):
            theirs = _layer(target)
            if theirs is not None and theirs > mine and not (theirs[0] == mine[0] and mine[0] != 0):
                offenders.append(f"{path.relative_to(PACKAGE)}:{line} imports {target}")
    assert not offenders, "imports that point up:\n" + "\n".join(offenders)


def test_experiments_import_no_bench():
    """bench may run the experiments (bench fit uses their scenes); the experiments never run a benchmark."""
    offenders = [f"{p.relative_to(PACKAGE)}:{line}" for p in (PACKAGE / "experiments").rglob("*.py")
                 for line, target in _runtime_imports(p) if target.startswith("tissue_sim_ros.bench")]
    assert not offenders, f"experiments importing benchmarks: {offenders}"


def test_envs_import_only_the_core():
    """The learning environments run where a learner installs them: the core's numpy, numba and python-fcl, and
    gymnasium; never ROS, nor Matplotlib (render/ selects its backend when imported)."""
    offenders = [f"{p.relative_to(PACKAGE)}:{line} imports {target}" for p in (PACKAGE / "envs").rglob("*.py")
                 for line, target in _runtime_imports(p)
                 if not target.startswith(("tissue_sim_ros.core", "tissue_sim_ros.envs"))]
    assert not offenders, offenders
    code = ("import sys, gymnasium as gym\n"
            "env = gym.make('tissue_sim_ros.envs:TissueSim/Retract-v0', render_mode='rgb_array')\n"
            "env.reset(seed=0); env.render()\n"
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_MODULES + ('matplotlib',)!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_no_code_imports_a_moved_path():
    """The old paths are aliases for users' scripts only; the package and its tests use the new ones."""
    from tissue_sim_ros._moved import MOVED, PREFIX

    old = {PREFIX + k for k in MOVED}
    files = _sources() + sorted((PACKAGE.parent / "test").glob("*.py")) + sorted((PACKAGE.parent / "scripts").glob("*.py"))
    offenders = [f"{p.name}:{line} imports {target}" for p in files if p.name != "test_layout.py"
                 for line, target in _runtime_imports(p) if target in old]
    assert not offenders, offenders


def test_moved_paths_are_gone_and_alias_their_new_home():
    from tissue_sim_ros._moved import MOVED, PREFIX

    for old, new in MOVED.items():
        assert not _is_module(PREFIX + old), f"{old} still exists beside its new home {new}"
        assert _is_module(PREFIX + new), f"{old} aliases {new}, which does not exist"
    code = ("import warnings, importlib\n"
            "warnings.simplefilter('error')\n"
            "import tissue_sim_ros.core.sim.scene as new\n"
            "try:\n    import tissue_sim_ros.core.scene\nexcept DeprecationWarning as w:\n    print(w)\n"
            "warnings.simplefilter('ignore')\n"
            "import tissue_sim_ros.core.scene as old\n"
            "from tissue_sim_ros.core import build_simulation\n"
            "print(old is new, old.build_simulation is build_simulation)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == ["tissue_sim_ros.core.scene moved to tissue_sim_ros.core.sim.scene; the old path goes in 0.3",
                   "True True"]


def test_no_import_cycle_in_bench():
    """The benchmarks import each other one way (a lazy import counts): a sweep with variants dispatched by the
    command line, not by a module that its variants import back."""
    modules = {_module_name(p): p for p in (PACKAGE / "bench").rglob("*.py")}
    graph = {m: {t for _, t in _runtime_imports(p) if t in modules and t != m} for m, p in modules.items()}
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def cycle_from(m: str, stack: list[str]) -> list[str] | None:
        state[m] = 1
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                return stack[stack.index(t):] + [m, t] if t in stack else [m, t]
            if t not in state and (found := cycle_from(t, stack + [m])):
                return found
        state[m] = 2
        return None

    cycles = [c for m in sorted(graph) if m not in state and (c := cycle_from(m, []))]
    assert not cycles, f"import cycles in bench/: {cycles}"


def test_core_sources_import_no_ros():
    offenders = []
    for path in CORE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            offenders += [f"{path.relative_to(PACKAGE)}: {n}" for n in names if n.split(".")[0] in ROS_MODULES]
    assert not offenders, f"core modules importing ROS: {offenders}"


def test_importing_every_core_module_loads_no_ros():
    modules = sorted(_module_name(p) for p in CORE.rglob("*.py"))
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "import tissue_sim_ros.core as c\n" + "".join(f"c.{n}\n" for n in ("resolve_config", "Config",
                                                                                    "Simulation", "build_simulation",
                                                                                    "rollout", "rollout_batch"))
            + f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_MODULES!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_core_reexports_the_entry_points():
    import tissue_sim_ros.core as core
    from tissue_sim_ros.core.config import Config, resolve_config
    from tissue_sim_ros.core.sim.batch import rollout_batch
    from tissue_sim_ros.core.sim.rollout import rollout
    from tissue_sim_ros.core.sim.scene import build_simulation
    from tissue_sim_ros.core.sim.simulation import Simulation

    assert (core.resolve_config, core.Config, core.Simulation, core.build_simulation, core.rollout,
            core.rollout_batch) == (resolve_config, Config, Simulation, build_simulation, rollout, rollout_batch)
    assert sorted(core.__all__) == sorted(["resolve_config", "Config", "Simulation", "build_simulation", "rollout",
                                           "rollout_batch"])
    with pytest.raises(AttributeError):
        core.no_such_name  # noqa: B018


def test_every_package_says_what_it_holds():
    """Each package's __init__ has a docstring of at least a sentence: what it holds (and may import)."""
    missing = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("__init__.py")
               if "__pycache__" not in p.parts and p.parent.name != "config"
               and len(ast.get_docstring(ast.parse(p.read_text())) or "") < 60]
    assert not missing, f"packages without a docstring saying what they hold: {missing}"


#: Modules past MAX_MODULE_LINES that are still to be split by job (none: add one here only with a plan to split it).
LONG_MODULES_TO_SPLIT: set[str] = set()
MAX_MODULE_LINES = 720
MAX_CORE_FUNCTION_LINES = 100
MAX_KERNEL_ARGUMENTS = 15
#: The ROS layer is held tighter: its modules and functions are read by whoever maintains a node next.
MAX_ROS_MODULE_LINES = 600
MAX_ROS_FUNCTION_LINES = 80


def test_no_module_is_past_about_700_lines():
    """A module past about 700 lines holds more than one job: split it (no docstring excuses the size)."""
    long = [f"{p.relative_to(PACKAGE)} ({n} lines)" for p in _sources()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
            and str(p.relative_to(PACKAGE)) not in LONG_MODULES_TO_SPLIT]
    assert not long, f"modules past {MAX_MODULE_LINES} lines: {long}"


def test_ros_modules_and_functions_are_short():
    """In ros/ no module passes about 600 lines and no function about 80: a node's parts, a bag's jobs and a
    message kind each have a module, and a long function is a job of its own waiting for a name."""
    long_modules, long_functions = [], []
    for path in sorted((PACKAGE / "ros").rglob("*.py")):
        n = len(path.read_text().splitlines())
        if n > MAX_ROS_MODULE_LINES:
            long_modules.append(f"{path.relative_to(PACKAGE)} ({n} lines)")
        for fn in _functions(path):
            if fn.end_lineno - fn.lineno + 1 > MAX_ROS_FUNCTION_LINES:
                long_functions.append(f"{path.relative_to(PACKAGE)}:{fn.lineno} {fn.name} "
                                      f"({fn.end_lineno - fn.lineno + 1} lines)")
    assert not long_modules, f"ros/ modules past {MAX_ROS_MODULE_LINES} lines: {long_modules}"
    assert not long_functions, f"ros/ functions past {MAX_ROS_FUNCTION_LINES} lines: {long_functions}"


def _functions(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def test_core_functions_are_short_and_kernels_take_bundles():
    """In the core no function passes about 100 lines, and no numba kernel takes more than about 15 arguments:
    a kernel's arrays come in bundles (tuples), named where they are made."""
    long, wide = [], []
    for path in sorted(CORE.rglob("*.py")):
        for fn in _functions(path):
            where = f"{path.relative_to(PACKAGE)}:{fn.lineno} {fn.name}"
            if fn.end_lineno - fn.lineno + 1 > MAX_CORE_FUNCTION_LINES:
                long.append(f"{where} ({fn.end_lineno - fn.lineno + 1} lines)")
            n_args = len(fn.args.args) + len(fn.args.kwonlyargs)
            if any("njit" in ast.unparse(d) for d in fn.decorator_list) and n_args > MAX_KERNEL_ARGUMENTS:
                wide.append(f"{where} ({n_args} arguments)")
    assert not long, f"core functions past {MAX_CORE_FUNCTION_LINES} lines: {long}"
    assert not wide, f"kernels with more than {MAX_KERNEL_ARGUMENTS} arguments: {wide}"


def test_docstrings_quote_no_line_counts():
    """A module's size is read off the file, not written in its docstring (where it goes stale)."""
    import re

    stale = [str(p.relative_to(PACKAGE)) for p in _sources()
             if re.search(r"\b(past|about) \d+ lines\b|\(\d+ lines\)", ast.get_docstring(ast.parse(p.read_text())) or "")
             and str(p.relative_to(PACKAGE)) not in LONG_MODULES_TO_SPLIT]
    assert not stale, f"docstrings quoting their module's line count: {stale}"


def test_argparse_lives_in_the_cli_only():
    """The library layers take a Config and plain arguments; parsing a command line is the CLI's job."""
    offenders = []
    for path in _sources():
        if _module_name(path).startswith("tissue_sim_ros.cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            offenders += [f"{path.relative_to(PACKAGE)}:{node.lineno}" for n in names if n.split(".")[0] == "argparse"]
    assert not offenders, f"argparse outside cli/: {offenders}"


def test_every_command_is_a_cli_module():
    from importlib import import_module

    from tissue_sim_ros.cli import COMMANDS

    modules = [m for entry in COMMANDS.values() for m, _ in (entry.values() if isinstance(entry, dict) else [entry])]
    outside = [m for m in modules if not m.startswith("tissue_sim_ros.cli.")]
    assert not outside, f"commands whose argument parsing lives outside cli/: {outside}"
    for name in modules:
        module = import_module(name)
        assert all(hasattr(module, attr) for attr in ("HELP", "add_arguments", "run")), name
