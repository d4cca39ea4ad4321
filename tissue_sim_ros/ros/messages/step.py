"""One step's outputs as CDR bytes (:class:`StepEncoder`): the one encoding the node publishes and ``tissue-sim
replay`` writes, so a replayed bag means what a live one means, message for message."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .cdr import Stamp
from .scene import SceneEncoder, body_label
from .small import encode_float64, encode_float64_multiarray, encode_uint32, encode_wrench_stamped

#: The energy terms of ``tissue/energy/bodies``' columns, in order.
ENERGY_TERMS = ("inertial", "spring", "area", "total")
#: Columns of ``tissue/contact`` per body: touched (1/0), d* [m] (inf: beyond reach), particles moved by the contact
CONTACT_FIELDS = ("in_contact", "distance", "moved")

#: The outputs of a step (topic relative to the node's namespace -> type), as the node publishes them.
STEP_TOPICS: dict[str, str] = {
    "tissue/energy": "std_msgs/msg/Float64",
    "tissue/energy/inertial": "std_msgs/msg/Float64",
    "tissue/energy/spring": "std_msgs/msg/Float64",
    "tissue/energy/area": "std_msgs/msg/Float64",
    "tissue/energy/strain": "std_msgs/msg/Float64",
    "tissue/energy/potential": "std_msgs/msg/Float64",
    "tissue/energy/contact": "std_msgs/msg/Float64",
    "tissue/energy/bodies": "std_msgs/msg/Float64MultiArray",
    "tissue/contact": "std_msgs/msg/Float64MultiArray",
    "tool/wrench": "geometry_msgs/msg/WrenchStamped",
    "tissue/points": "sensor_msgs/msg/PointCloud2",
    "tissue/markers": "visualization_msgs/msg/MarkerArray",
}

#: The further outputs of a step when the tool is a grasper (msg_docs/topics.md): the attachment springs' term
#: dt^2 E_attach (a term of the total) and the number of particles held.
GRASP_TOPICS: dict[str, str] = {
    "tissue/energy/attach": "std_msgs/msg/Float64",
    "tool/grasped": "std_msgs/msg/UInt32",
}


@dataclass
class StepMessages:
    """The serialized outputs of one step, topic (relative, see :data:`STEP_TOPICS`) -> CDR bytes, in publishing order.

    A message that would carry NaN is left out: ``withheld`` says which and why.
    """

    messages: dict[str, bytes] = field(default_factory=dict)
    withheld: list[str] = field(default_factory=list)
    """Why a message was left out (non-finite positions, energy or reaction); empty when none was."""


class StepEncoder:
    """A step's outputs as CDR bytes, the one encoding the node publishes and ``tissue-sim replay`` writes.

    From a :class:`~tissue_sim_ros.core.sim.simulation.StepReport` and the state
    after the step: the scene energy and its terms (total and per body), the
    reaction wrench, the points with their signed strain, and the markers. So a
    replayed bag means what a live one means, message for message.

    Parameters
    ----------
    model : Model
        The simulation's model (mesh topology, rest lengths, bodies).
    tool : ToolShape, optional
        The tool (its marker's outline); None: no tool marker.
    strain_color_max, wire_width, wireframe
        Marker appearance (see :class:`SceneEncoder`).
    """

    def __init__(self, model: Any, tool: Any = None, *, strain_color_max: float = 0.2, wire_width: float = 0.002,
                 wireframe: bool = True) -> None:
        self.scene = SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body,
                                  tool_rounded_box=tool.rounded_box() if tool is not None else None,
                                  strain_color_max=strain_color_max, wire_width=wire_width, wireframe=wireframe,
                                  tool_outline_local=tool.outline() if tool is not None and tool.kind == "grasper"
                                  else None, grasper=tool is not None and tool.kind == "grasper")
        self.body_label = body_label(model.body_names)
        """``tissue/energy/bodies``' row label: ``body:`` and the body names."""
        self._particle_body = np.asarray(model.particle_body, dtype=np.int64)
        self._n_bodies = len(model.body_names)
        self.grasper = tool is not None and tool.kind == "grasper"
        """Encode :data:`GRASP_TOPICS` too."""

    def strain(self, q: np.ndarray) -> np.ndarray:
        """Signed vertex strain of positions ``q`` (N, 2) [m], shape (N,)."""
        return self.scene.vertex_strain(q)

    def encode(self, stamp: Stamp, frame_id: str, report: Any, q: np.ndarray, *, points: bool = True,
               markers: bool = False, tool_pose: tuple[float, float, float] | None = None,
               tool_stamp: Stamp | None = None) -> StepMessages:
        """The messages of the step ``report`` that left positions ``q`` (N, 2) [m], all stamped ``stamp``.

        Energy is left out of a step that diverged (its state was restored); with
        non-finite positions nothing is encoded. ``points`` / ``markers`` choose
        whether this step carries them (the node's rates); the tool marker
        carries ``tool_stamp`` (default ``stamp``).
        """
        out = StepMessages()
        if not np.isfinite(q).all():
            # the Simulation restores the last good state, so this is a bug guard: never publish NaN
            out.withheld.append(f"step {report.step} left non-finite positions; nothing published")
            return out
        e = report.energy
        if not report.diverged:
            terms = np.stack([e.inertial, e.spring, e.area, e.total], axis=1)  # (B, 4)
            if np.isfinite(terms).all() and np.isfinite(e.potential).all():
                out.messages["tissue/energy"] = encode_float64(float(terms[:, 3].sum()))
                for i, term in enumerate(ENERGY_TERMS[:3]):
                    out.messages[f"tissue/energy/{term}"] = encode_float64(float(terms[:, i].sum()))
                # material: dt^2 E_strain (a term of the total) and the potential energy itself [J]
                out.messages["tissue/energy/strain"] = encode_float64(float(e.strain.sum()))
                out.messages["tissue/energy/potential"] = encode_float64(e.scene_potential)
                # barrier contact: dt^2 kappa sum b, the contact barriers' term of the total (0 otherwise)
                out.messages["tissue/energy/contact"] = encode_float64(float(np.sum(e.contact)))
                out.messages["tissue/energy/bodies"] = encode_float64_multiarray(
                    terms, [self.body_label, "term:" + ",".join(ENERGY_TERMS)])
            else:
                out.withheld.append(f"step {report.step}: non-finite energy not published")
        if self.grasper:
            attach = getattr(e, "attach", None)
            value = float(np.sum(attach)) if attach is not None else 0.0
            if not report.diverged and math.isfinite(value):
                out.messages["tissue/energy/attach"] = encode_float64(value)
            out.messages["tool/grasped"] = encode_uint32(len(getattr(report, "grasped", ())))
        out.messages["tissue/contact"] = self.contact(report)
        f, tz = report.reaction_force, report.reaction_torque
        if np.isfinite(f).all() and math.isfinite(tz):
            out.messages["tool/wrench"] = encode_wrench_stamped(stamp, frame_id, (float(f[0]), float(f[1]), 0.0),
                                                                (0.0, 0.0, float(tz)))
        else:
            out.withheld.append(f"step {report.step}: non-finite reaction not published")
        if points or markers:
            strain = self.strain(q)
            if points:
                out.messages["tissue/points"] = self.scene.point_cloud(stamp, frame_id, q, strain)
            if markers:
                out.messages["tissue/markers"] = self.scene.markers(
                    stamp, frame_id, q, strain, tool_pose=tool_pose, tool_stamp=tool_stamp,
                    contact_particles=report.contact_particles, grasped_particles=getattr(report, "grasped", None))
        return out

    def contact(self, report: Any) -> bytes:
        """``tissue/contact`` of a step: per body, whether the tool touches it (the Simulation's ``in_contact``:
        paper model d* < alpha, projection any particle pushed), d* [m] (+inf where the tool is beyond the
        contact's reach and d* was not computed; never NaN), and how many of its particles the contact moved."""
        moved = np.bincount(self._particle_body[np.asarray(report.contact_particles, dtype=np.int64)],
                            minlength=self._n_bodies)[: self._n_bodies]
        d_star = np.where(np.isnan(report.d_star), np.inf, report.d_star)
        table = np.column_stack([np.asarray(report.in_contact, dtype=np.float64), d_star, moved.astype(np.float64)])
        return encode_float64_multiarray(table, [self.body_label, "field:" + ",".join(CONTACT_FIELDS)])

    def state(self, stamp: Stamp, frame_id: str, q: np.ndarray) -> StepMessages:
        """Points and markers of a state outside a step (after a reset): no energy, no wrench, no tool."""
        strain = self.strain(q)
        return StepMessages({"tissue/points": self.scene.point_cloud(stamp, frame_id, q, strain),
                             "tissue/markers": self.scene.markers(stamp, frame_id, q, strain)})

    def rest_markers(self, stamp: Stamp, frame_id: str, model: Any) -> bytes:
        """``tissue/rest_mesh`` of ``model``."""
        return self.scene.rest_markers(stamp, frame_id, model.particle_q0, model.particle_pinned)
