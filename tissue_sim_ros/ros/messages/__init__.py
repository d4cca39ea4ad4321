"""Simulation arrays <-> serialized ROS 2 messages (CDR bytes), without rclpy or any message package.

rclpy's ``Publisher.publish`` takes CDR bytes as they are, and ``raw=True`` subscriptions deliver them, so the
node, the recorders and ``tissue-sim replay`` never build message objects:

* :mod:`.small` (Float64, UInt32, Float64MultiArray, PoseStamped, TwistStamped, WrenchStamped, JointState) and
  :mod:`.points` (PointCloud2, whose points are one byte array) through ``rosbags``' typestore;
* :mod:`.markers` (Marker, MarkerArray): written by hand from NumPy arrays with the writer and reader of
  :mod:`.cdr`, since a message object per point is what makes a 5,000-triangle array slow through the typestore
  and through rclpy alike (the numbers: docs/benchmarks/ros.md);
* :mod:`.scene` (:class:`SceneEncoder`: a scene's points, markers and rest mesh into preallocated buffers) and
  :mod:`.step` (:class:`StepEncoder`: a step's outputs, the one encoding the node publishes and replay writes).

``test/test_ros_messages.py`` checks every encoder against rclpy's serializer, both ways.
"""
from __future__ import annotations

from .cdr import CDR_LE_HEADER, CdrReader, CdrWriter, Stamp
from .markers import (
    ACTION_ADD,
    ACTION_DELETE,
    ACTION_DELETEALL,
    MARKER_ARROW,
    MARKER_CUBE,
    MARKER_CUBE_LIST,
    MARKER_CYLINDER,
    MARKER_LINE_LIST,
    MARKER_LINE_STRIP,
    MARKER_MESH_RESOURCE,
    MARKER_POINTS,
    MARKER_SPHERE,
    MARKER_SPHERE_LIST,
    MARKER_TEXT_VIEW_FACING,
    MARKER_TRIANGLE_LIST,
    DecodedMarker,
    MarkerSpec,
    decode_marker_array,
    encode_marker,
    encode_marker_array,
    points3,
    read_marker,
)
from .points import POINT_DTYPE, POINTFIELD_DATATYPES, decode_point_cloud, encode_point_cloud
from .scene import SceneEncoder, body_label, strain_colormap
from .small import (
    decode_float64,
    decode_float64_multiarray,
    decode_joint_state,
    decode_pose_stamped,
    decode_twist_stamped,
    decode_uint32,
    decode_wrench_stamped,
    encode_float64,
    encode_float64_multiarray,
    encode_joint_state,
    encode_pose_stamped,
    encode_twist_stamped,
    encode_uint32,
    encode_wrench_stamped,
    pose_stamped,
    twist_stamped,
)
from .step import CONTACT_FIELDS, ENERGY_TERMS, GRASP_TOPICS, STEP_TOPICS, StepEncoder, StepMessages

__all__ = [
    "CDR_LE_HEADER", "CdrReader", "CdrWriter", "Stamp",
    "ACTION_ADD", "ACTION_DELETE", "ACTION_DELETEALL", "MARKER_ARROW", "MARKER_CUBE", "MARKER_CUBE_LIST",
    "MARKER_CYLINDER", "MARKER_LINE_LIST", "MARKER_LINE_STRIP", "MARKER_MESH_RESOURCE", "MARKER_POINTS",
    "MARKER_SPHERE", "MARKER_SPHERE_LIST", "MARKER_TEXT_VIEW_FACING", "MARKER_TRIANGLE_LIST", "DecodedMarker",
    "MarkerSpec", "decode_marker_array", "encode_marker", "encode_marker_array", "points3", "read_marker",
    "POINT_DTYPE", "POINTFIELD_DATATYPES", "decode_point_cloud", "encode_point_cloud",
    "SceneEncoder", "body_label", "strain_colormap",
    "decode_float64", "decode_float64_multiarray", "decode_joint_state", "decode_pose_stamped",
    "decode_twist_stamped", "decode_uint32", "decode_wrench_stamped", "encode_float64", "encode_float64_multiarray",
    "encode_joint_state", "encode_pose_stamped", "encode_twist_stamped", "encode_uint32", "encode_wrench_stamped",
    "pose_stamped", "twist_stamped",
    "CONTACT_FIELDS", "ENERGY_TERMS", "GRASP_TOPICS", "STEP_TOPICS", "StepEncoder", "StepMessages",
]
