"""rosbag2 bags with the ``rosbags`` and ``mcap`` libraries, by job: :mod:`.write`, :mod:`.recover`, :mod:`.read`,
:mod:`.tracks` (tool trajectories), and how the bytes sit on disk, :mod:`.storage`.

No rclpy here: ``tissue-sim replay`` reads bags offline; ``tissue-sim record`` and the ROS node write with
:class:`BagWriter` (thread-safe, so an executor's callbacks can call it). Bags are ordinary rosbag2 bags (a
directory with ``metadata.yaml`` and one ``.mcap`` or ``.db3`` file) with the Jazzy type names, message
definitions and type hashes, so they open in ``ros2 bag``, Foxglove and PlotJuggler. docs/bags.md describes them.
"""
from __future__ import annotations

from ..typestore import typestore
from .read import Bag
from .recover import recover_bag, recover_mcap
from .storage import STORAGES, durable_custom_data
from .tracks import (
    JAW_SUFFIXES,
    JAW_TYPE,
    NODE_TOOL_OUTPUTS,
    POSE_TYPES,
    SKIP_REASONS,
    TF_TYPE,
    TWIST_TYPES,
    BadSampleError,
    ToolTrack,
    is_jaw_topic,
    is_node_tool_output,
    read_tool_track,
    tool_candidates,
)
from .write import BagWriter

__all__ = ["STORAGES", "POSE_TYPES", "TWIST_TYPES", "JAW_TYPE", "JAW_SUFFIXES", "TF_TYPE", "NODE_TOOL_OUTPUTS",
           "SKIP_REASONS", "BagWriter", "Bag", "ToolTrack", "BadSampleError", "read_tool_track", "is_jaw_topic",
           "is_node_tool_output", "tool_candidates", "recover_mcap", "recover_bag", "durable_custom_data",
           "typestore"]
