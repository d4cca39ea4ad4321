"""The node's publishers, made once (topics and QoS: msg_docs/topics.md) and handed to the parts that publish."""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import Float64, Float64MultiArray, UInt32
from visualization_msgs.msg import MarkerArray

from .. import qos
from ..messages import ENERGY_TERMS
from ..raw_publish import GilFreePublisher

#: The energy terms with a topic of their own (``tissue/energy/TERM``): the paper's three, the material's strain
#: (a term of the total) and potential energy [J], and the grasp's attachment springs.
TERM_TOPICS = (*ENERGY_TERMS[:3], "strain", "potential", "contact", "attach")


@dataclass(frozen=True)
class NodePublishers:
    """One publisher per output topic (``energy_terms``: one per :data:`TERM_TOPICS`)."""

    markers: Any
    points: Any
    rest: Any
    wrench: Any
    energy: Any
    energy_terms: dict[str, Any]
    energy_bodies: Any
    contact: Any
    grasped: Any
    diagnostics: Any
    applied_pose: Any
    applied_twist: Any
    applied_jaw: Any

    @classmethod
    def create(cls, create_publisher: Callable[..., Any]) -> "NodePublishers":
        """Every publisher, made with ``create_publisher`` (a node's); the markers' publishes let the GIL go
        (:mod:`~tissue_sim_ros.ros.raw_publish`), so the step thread runs while 1 MB goes to DDS."""
        pub = create_publisher
        return cls(
            markers=GilFreePublisher(pub(MarkerArray, "tissue/markers", qos.state_stream(qos.MARKER_DEPTH))),
            points=pub(PointCloud2, "tissue/points", qos.state_stream()),
            rest=pub(MarkerArray, "tissue/rest_mesh", qos.latched()),
            wrench=pub(WrenchStamped, "tool/wrench", qos.state_stream()),
            energy=pub(Float64, "tissue/energy", qos.energy()),
            energy_terms={term: pub(Float64, f"tissue/energy/{term}", qos.energy()) for term in TERM_TOPICS},
            energy_bodies=pub(Float64MultiArray, "tissue/energy/bodies", qos.energy()),
            contact=pub(Float64MultiArray, "tissue/contact", qos.energy()),
            grasped=pub(UInt32, "tool/grasped", qos.energy()),
            diagnostics=pub(DiagnosticArray, "/diagnostics", qos.diagnostics()),
            applied_pose=pub(PoseStamped, "tool/applied_pose", qos.state_stream()),
            applied_twist=pub(TwistStamped, "tool/applied_twist", qos.state_stream()),
            applied_jaw=pub(JointState, "tool/applied_jaw", qos.state_stream()),
        )

    def wrapped(self, wrap: Callable[[Any], Any]) -> "NodePublishers":
        """The same publishers, each passed through ``wrap`` (recording: publish and write into the bag)."""
        changes = {f.name: wrap(getattr(self, f.name)) for f in fields(self) if f.name != "energy_terms"}
        return replace(self, **changes, energy_terms={k: wrap(p) for k, p in self.energy_terms.items()})

    def every(self) -> list[Any]:
        return [getattr(self, f.name) for f in fields(self) if f.name != "energy_terms"] + list(self.energy_terms.values())

    def step_topics(self) -> dict[str, Any]:
        """The publisher of each step output (:data:`~tissue_sim_ros.ros.messages.STEP_TOPICS` and the grasp's)."""
        return {"tissue/energy": self.energy, **{f"tissue/energy/{k}": p for k, p in self.energy_terms.items()},
                "tissue/energy/bodies": self.energy_bodies, "tissue/contact": self.contact,
                "tool/grasped": self.grasped, "tool/wrench": self.wrench, "tissue/points": self.points,
                "tissue/markers": self.markers}
