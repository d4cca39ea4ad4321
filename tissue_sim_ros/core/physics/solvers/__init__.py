"""The solvers."""
from .constraint import SolveInfo, Solver  # noqa: F401
from .ordering import (  # noqa: F401
    PARALLEL_MIN_PARTICLES,
    colour_constraints,
    partition_constraints,
    partition_particles,
    wavefront_order,
)
