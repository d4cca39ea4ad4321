"""The node's parameters: declared resolved, and changed at run time as a whole or not at all.

The node reads its settings from its typed, resolved
:class:`~tissue_sim_ros.core.config.Config` (:class:`CurrentConfig`: ``.sim``,
``.scene``, ``.tool``, ``.node``), never from strings. At start every
parameter is resolved through :func:`~tissue_sim_ros.core.config.resolve_config`
and declared with its resolved value. A run-time set is checked first
(:meth:`ParameterChanges.pre_set`: an unknown name refused naming the closest
known one, an integer for a float made a float, a method alias expanded), then
resolved and checked as a whole (:meth:`ParameterChanges.on_set`); if that
succeeds the node takes the new Config (:class:`CurrentConfig`) and rebuilds what depends on a changed
value (the simulation's tuning, the encoder, the frames, the timers).
"""
from __future__ import annotations

from typing import Any, Callable

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter

from ...core.config import FOREIGN_PREFIXES, METHOD_ALIASES, Config, closest_name, resolve_config
from ...core.errors import InputError
from ..parameters import BY_NAME, PARAMETERS, descriptor, parameter_value, take_overrides


class UnknownParameter(ParameterNotDeclaredException):
    """A set of a name the node does not have; rclpy's services answer with this message as the reason."""

    def __init__(self, name: str) -> None:
        near = closest_name(name)
        hint = f"; did you mean {near!r}?" if near else "; the names are listed in msg_docs/parameters.md"
        Exception.__init__(self, f"unknown parameter {name!r}{hint}")


class CurrentConfig:
    """The node's configuration as it is now: the parts read :attr:`node` (its NodeConfig) at each use, and a
    successful run-time set replaces :attr:`value` as a whole."""

    def __init__(self, value: Config) -> None:
        self.value = value

    @property
    def node(self) -> Any:
        """The node's own settings (``Config.node``)."""
        return self.value.node


def declare_parameters(node: Any) -> Config:
    """Resolve the parameters given to the node (file and -p) through the front door; declare them resolved.

    An unknown name, a type mismatch or a bad value raises InputError naming it. Each parameter is declared
    with its descriptor and resolved value (a method alias such as ``xpbd_substep`` reads back as ``method:
    xpbd`` with its substeps and iterations), so ``ros2 param get`` shows what the simulation runs.
    """
    given = take_overrides(node)
    cfg = resolve_config(overrides={k: v for k, v in given.items() if not k.startswith(FOREIGN_PREFIXES)},
                         source=f"the parameters of {node.get_name()}")
    flat = cfg.flat()
    for spec in PARAMETERS:
        node.declare_parameter(spec.name, flat[spec.name], descriptor(spec), ignore_override=True)
    return cfg


class ParameterChanges:
    """The node's pre-set and set callbacks (rclpy's ``add_pre_set_parameters_callback`` and
    ``add_on_set_parameters_callback``).

    Parameters
    ----------
    config : CurrentConfig
        Replaced as a whole by a successful set.
    has_parameter : callable
        Whether the node declares a name (the node's ``has_parameter``).
    check : callable
        Called with (new Config, names changed) before it is taken: raises InputError when the node cannot take it
        (a plane frame the frames refuse; a simulation retuned to it).
    apply : callable
        Called with (old NodeConfig, new NodeConfig) once it is taken: rebuilds what depends on them.
    """

    def __init__(self, config: CurrentConfig, has_parameter: Callable[[str], bool],
                 check: Callable[[Config, list[str]], None], apply: Callable[[Any, Any], None]) -> None:
        self.config = config
        self._has_parameter = has_parameter
        self._check = check
        self._apply = apply

    def pre_set(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set, before rclpy's own checks: an unknown name is refused naming the closest known one (rclpy's
        reason names neither); an integer for a float parameter becomes a float (the parameter stays a double
        for every reader); a method alias is expanded (:meth:`expand_alias`)."""
        for p in params:
            if not self._has_parameter(p.name):
                raise UnknownParameter(p.name)
        params = [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                  if p.type_ == Parameter.Type.INTEGER and p.name in BY_NAME and BY_NAME[p.name].kind is float else p
                  for p in params]
        return self.expand_alias(params)

    def expand_alias(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set: a method alias set at run time becomes the orthogonal values it resolves to."""
        method = next((p for p in params if p.name == "method"), None)
        if method is None or method.value not in METHOD_ALIASES:
            return params
        current = self.config.value
        try:
            cfg = current.replace(**{p.name: parameter_value(p.value) for p in params if p.name in BY_NAME})
        except InputError:
            return params  # the set callback rejects it with the reason
        names = {p.name for p in params}
        out = [p for p in params if p.name != "method"] + [Parameter("method", value=cfg.sim.method)]
        for key in METHOD_ALIASES[method.value]:
            if key != "method" and key not in names and getattr(cfg.sim, key) != getattr(current.sim, key):
                out.append(Parameter(key, value=getattr(cfg.sim, key)))
        return out

    def on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Check a set of tunable parameters as a whole; apply it only if all are fine."""
        changes: dict[str, Any] = {}
        for p in params:
            spec = BY_NAME.get(p.name)
            if spec is None:
                continue  # use_sim_time and friends: rclpy handles them
            if spec.read_only:
                return SetParametersResult(successful=False, reason=f"parameter {p.name} is read-only: restart the node to change it")
            changes[p.name] = parameter_value(p.value)
        if not changes:
            return SetParametersResult(successful=True)
        current = self.config.value
        try:
            cfg = current.replace(**changes)
            self._check(cfg, current.changed(cfg))
        except InputError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.config.value = cfg
        self._apply(current.node, cfg.node)
        return SetParametersResult(successful=True)
