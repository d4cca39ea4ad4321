"""Old import paths of modules that moved, kept working for one release (0.2) with a DeprecationWarning.

The house was laid out in rooms (core/mesh, physics, contact, sim, plan, fit, timing; cli/;
render/): ``import tissue_sim_ros.core.scene`` now finds ``tissue_sim_ros.core.sim.scene``
and warns once, naming the new path. The alias is the same module object, so a name
imported either way is the same name. Remove this module in 0.3.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType

#: old dotted path -> new dotted path (without the ``tissue_sim_ros.`` prefix)
MOVED = {
    "resources": "core.resources",
    "render_fit": "render.fit",
    "cli_config": "cli.config",
    "cli_fit": "cli.fit",
    "cli_mesh": "cli.mesh",
    "cli_play": "cli.play",
    "cli_record": "cli.record",
    "cli_replay": "cli.replay",
    "experiments.cli": "cli.experiment",
    "experiments.trajectories": "core.timing.trajectories",
    "core.scene": "core.sim.scene",
    "core.simulation": "core.sim.simulation",
    "core.snapshot": "core.sim.snapshot",
    "core.rollout": "core.sim.rollout",
    "core.batch": "core.sim.batch",
    "core.backends": "core.sim.backends",
    "core.model": "core.physics.model",
    "core.material": "core.physics.material",
    "core.kernels": "core.physics.kernels",
    "core.step_kernels": "core.physics.step_kernels",
    "core.violated_jacobi": "core.physics.violated_jacobi",
    "core.solvers": "core.physics.solvers",
    "core.statics": "core.physics.statics",
    "core.minimize": "core.physics.minimize",
    "core.energy": "core.physics.energy",
    "core.strain": "core.physics.strain",
    "core.sleeping": "core.physics.solvers.sleeping",
    "core.physics.sleeping": "core.physics.solvers.sleeping",
    "core.tool": "core.contact.tool",
    "core.collision": "core.contact.collision",
    "core.tool_checks": "core.contact.tool_checks",
    "core.planning": "core.plan.insertion",
    "core.tracking": "core.fit.tracking",
    "core.fitting": "core.fit.fitting",
    "core.stamps": "core.timing.stamps",
    "core.frames": "core.timing.frames",
    "core.phase_lock": "core.timing.phase_lock",
    "core.trajectories": "core.timing.trajectories",
    "bench.tune": "tune.settings",
    "bench.tune_material": "tune.material",
}
PREFIX = "tissue_sim_ros."


class _Alias(importlib.abc.Loader):
    def __init__(self, module: ModuleType) -> None:
        self.module = module

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return self.module

    def exec_module(self, module: ModuleType) -> None:
        pass


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        new = MOVED.get(fullname[len(PREFIX):]) if fullname.startswith(PREFIX) else None
        if new is None:
            return None
        warnings.warn(f"{fullname} moved to {PREFIX}{new}; the old path goes in 0.3", DeprecationWarning,
                      stacklevel=3)
        return importlib.util.spec_from_loader(fullname, _Alias(importlib.import_module(PREFIX + new)))


def install() -> None:
    """Put the finder on ``sys.meta_path`` once."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())
