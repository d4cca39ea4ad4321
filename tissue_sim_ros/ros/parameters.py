"""The node's parameters: the one table of :mod:`tissue_sim_ros.core.config`, seen from ROS.

Every parameter (name, type, unit, range, description, read-only) is declared
once, in :data:`tissue_sim_ros.core.config.PARAMETERS`; the node declares each
with a ``ParameterDescriptor`` built here, and ``msg_docs/parameters.md`` is
generated from the same table (``python -m tissue_sim_ros.ros.parameters``
prints the markdown; a test checks it is current).

Model-defining parameters (the mesh, dt, mass, boundary lines, tool shape,
lock-step) are read-only: changing them means a new scene, so restart the node.
The rest are tunable while running; a set is resolved and checked as a whole
first (:meth:`Config.replace <tissue_sim_ros.core.config.Config.replace>`) and
rejected with the reason when a value is bad.
"""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor

from ..core.config import BY_NAME, PARAMETERS, SIM_NAMES, ParamSpec, coerce, markdown_table

__all__ = ["BY_NAME", "PARAMETERS", "SIM_NAMES", "ParamSpec", "coerce", "descriptor", "markdown_table"]


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of one parameter: description with its unit, read-only flag.

    Dynamic typing: a YAML ``1`` for a float must not abort with rclpy's type error;
    :func:`~tissue_sim_ros.core.config.coerce` checks the type and names the parameter instead.
    """
    return ParameterDescriptor(name=spec.name, description=spec.description + (f" [{spec.unit}]" if spec.unit else ""),
                               read_only=spec.read_only, dynamic_typing=True)


def parameter_value(value: Any) -> Any:
    """A rclpy parameter value as plain Python (rclpy gives lists as arrays)."""
    return list(value) if hasattr(value, "tolist") or isinstance(value, tuple) else value


#: Parameters rclpy declares for every node: left as they are.
RCLPY_OWN = ("use_sim_time", "start_type_description_service")


def take_overrides(node: Any) -> dict[str, Any]:
    """What a node was given (its parameter files, ``-p``, ``parameter_overrides``), as plain Python, undeclared
    again so that the node declares each with its own descriptor.

    The node must be made with ``automatically_declare_parameters_from_overrides=True``: rclpy then declares
    every override as given, which its public API reads back (rclpy keeps the overrides themselves private).
    """
    names = [n for n in node.get_parameters_by_prefix("") if n not in RCLPY_OWN]
    given = {p.name: parameter_value(p.value) for p in node.get_parameters(names)}
    for name in names:
        node.undeclare_parameter(name)
    return given


if __name__ == "__main__":
    print(markdown_table())
