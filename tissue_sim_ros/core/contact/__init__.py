"""The tool and what it touches: the tool's shape, pose, twist and trajectories (``tool``),
the python-fcl detection and the paper's and the projection contact models (``collision``),
and the run-time checks of a step against the tool (``tool_checks``: penetration,
tunnelling, a buried tool).

It imports nothing of the physics at run time (the Model and State appear in its
type hints only), so the physics may call its array kernels from inside the solver loop.
"""
