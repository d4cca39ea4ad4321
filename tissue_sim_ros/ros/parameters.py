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


if __name__ == "__main__":
    print(markdown_table())
