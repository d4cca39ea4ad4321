"""The tissue's physics: the frozen :class:`~.model.Model` and its :class:`~.model.State`, the
material, the numba kernels and the solvers that step them, and the energy a step stores.

``params`` declares the simulation's parameters, one row each (``SimParams`` is made from them);
``model`` builds the arrays (rest lengths and areas, masses, pins, material tables);
``kernels``, ``step_kernels``, ``material``, ``attach`` (a grasper's attachment springs) and
``violated_jacobi`` (the paper authors' Jacobi) are the ``@njit`` kernels; ``solvers`` and ``sleeping`` run them as PBD and XPBD
(Gauss-Seidel, Jacobi, substeps); ``statics`` and ``minimize`` find rest shapes by
Newton; ``energy`` and ``strain`` measure a state; ``ldlt`` is a sparse LDL^T for a matrix refactored many
times on one pattern (numba, numpy and scipy only). It may import :mod:`..mesh` and
the array kernels of :mod:`..contact` (the tool is kept out of the tissue inside the
solver loop), never :mod:`..sim` or above.
"""
