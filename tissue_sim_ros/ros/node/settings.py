"""The node's parameters: declared resolved, and changed at run time as a whole or not at all.

The node reads its settings from its typed, resolved
:class:`~tissue_sim_ros.core.config.Config` (``node.config``: ``.sim``,
``.scene``, ``.tool``, ``.node``), never from strings. At start every
parameter is resolved through :func:`~tissue_sim_ros.core.config.resolve_config`
and declared with its resolved value. A run-time set is checked first
(:meth:`ParameterChanges.pre_set`: an unknown name refused naming the closest
known one, an integer for a float made a float, a method alias expanded), then
resolved and checked as a whole (:meth:`ParameterChanges.on_set`); if that
succeeds the node takes the new Config and rebuilds what depends on a changed
value (the simulation's tuning, the encoder, the frames, the timers).
"""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter

from ...core.config import FOREIGN_PREFIXES, METHOD_ALIASES, Config, closest_name, resolve_config
from ...core.errors import InputError
from ..parameters import BY_NAME, PARAMETERS, SIM_NAMES, descriptor, parameter_value


class UnknownParameter(ParameterNotDeclaredException):
    """A set of a name the node does not have; rclpy's services answer with this message as the reason."""

    def __init__(self, name: str) -> None:
        near = closest_name(name)
        hint = f"; did you mean {near!r}?" if near else "; the names are listed in msg_docs/parameters.md"
        Exception.__init__(self, f"unknown parameter {name!r}{hint}")


def declare_parameters(node: Any) -> Config:
    """Resolve the parameters given to the node (file and -p) through the front door; declare them resolved.

    An unknown name, a type mismatch or a bad value raises InputError naming it.
    Each parameter is declared with its resolved value (a method alias such as
    ``xpbd_substep`` reads back as ``method: xpbd`` with its substeps and
    iterations), so ``ros2 param get`` shows what the simulation runs.
    """
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps the file's and -p values here
    given = {name: parameter_value(p.value) for name, p in overrides.items()
             if not name.startswith(FOREIGN_PREFIXES)}
    cfg = resolve_config(overrides=given, source=f"the parameters of {node.get_name()}")
    flat = cfg.flat()
    for spec in PARAMETERS:
        node.declare_parameter(spec.name, flat[spec.name], descriptor(spec), ignore_override=True)
    return cfg


class ParameterChanges:
    """The node's pre-set and set callbacks (rclpy's ``add_pre_set_parameters_callback`` and
    ``add_on_set_parameters_callback``).

    Parameters
    ----------
    node : TissueSimNode
        Its ``config`` is replaced on a successful set; its simulation, frames, outputs and timers follow.
    """

    def __init__(self, node: Any) -> None:
        self.node = node

    def pre_set(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set, before rclpy's own checks: an unknown name is refused naming the closest known one (rclpy's
        reason names neither); an integer for a float parameter becomes a float (the parameter stays a double
        for every reader); a method alias is expanded (:meth:`expand_alias`)."""
        for p in params:
            if not self.node.has_parameter(p.name):
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
        current = self.node.config
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
        node = self.node
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
        try:
            cfg = node.config.replace(**changes)
            changed = node.config.changed(cfg)
            if "frame_id" in changed:
                node.frames.check_plane(cfg.node.frame_id)
            if any(name in SIM_NAMES for name in changed):
                node.sim.retune(cfg)
        except InputError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        old, new = node.config.node, cfg.node
        node.config = cfg
        self._apply(old, new)
        return SetParametersResult(successful=True)

    def _apply(self, old: Any, new: Any) -> None:
        """Rebuild what depends on the node settings that changed from ``old`` to ``new`` (NodeConfig)."""
        node = self.node
        if new.tf_tolerance != old.tf_tolerance:
            node.frames.buffer.tolerance_ns = int(new.tf_tolerance * 1e9)
        if (new.strain_color_max, new.wire_width, new.markers_wireframe) != \
                (old.strain_color_max, old.wire_width, old.markers_wireframe):
            node.outputs.encoder = node.outputs.make_encoder()
        if new.frame_id != old.frame_id:
            node.frames.set_plane(node, new.frame_id)  # poses in the old frame are no longer the plane's
            node.outputs.publish_rest_mesh()
        if node.marker_timer is not None and new.marker_rate != old.marker_rate:
            node.destroy_timer(node.marker_timer)
            node.marker_timer = node.create_timer(1.0 / new.marker_rate, node.outputs.flush_markers)
        if new.diagnostics_rate != old.diagnostics_rate:
            node.destroy_timer(node.diagnostics_timer)
            node.diagnostics_timer = node.create_timer(1.0 / new.diagnostics_rate, node.outputs.publish_diagnostics)
        if new.paused != old.paused:
            node.get_logger().info("paused" if new.paused else "running")
