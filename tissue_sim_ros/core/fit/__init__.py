"""Real to sim: tracked tissue points bound to the mesh, simulated tracks under a recorded
tool (``tracking``), and the identification of the material's parameters that makes them
match (``fitting``: least squares or CMA-ES). Built on :mod:`..sim`.
"""
