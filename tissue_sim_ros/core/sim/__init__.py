"""One scene stepped through time, and many at once: :class:`~.simulation.Simulation` (a
config -> mesh -> model -> solver, ``step(pose, twist, jaw=...) -> StepReport``), the grasper's jaw
(``grasp``), its snapshots,
rollouts of a tool path, batches of candidate paths (serial, a process pool or Ray:
``backends``) and ``scene.build_simulation``, the shortest way from parameters to a
running simulation. Built on :mod:`..config`, :mod:`..physics` and :mod:`..contact`.
"""
