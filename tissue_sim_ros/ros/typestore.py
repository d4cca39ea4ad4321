"""The ROS 2 Jazzy message types of ``rosbags``' typestore: their definitions and type hashes for bags
(:mod:`.bags`), and CDR for the small messages (:mod:`.messages.small`). No rclpy: it runs offline."""
from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore


@lru_cache(maxsize=1)
def typestore() -> "Typestore":
    """The ROS 2 Jazzy typestore of ``rosbags`` (type names, definitions, hashes, CDR)."""
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    return get_typestore(Stores.ROS2_JAZZY)


def msg_class(msgtype: str) -> Any:
    """The typestore's class of a message type (``"std_msgs/msg/Float64"``)."""
    return typestore().types[msgtype]
