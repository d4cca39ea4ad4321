"""``tissue-sim tune``: the cheapest model that meets an error tolerance, written as a parameter file.

A product command, not a benchmark: it chooses a scene's mesh spacing, method, iterations and substeps
(:mod:`.settings`; for ``material: neo_hookean``, its meshes, substeps and iterations, :mod:`.material`) and
writes them in the format of ``config/tissue_sim.yaml``. It measures every candidate against the exact
references the benchmarks use (:mod:`tissue_sim_ros.bench.accuracy`, :mod:`tissue_sim_ros.bench.reference`),
so it sits above them; only the command line (:mod:`tissue_sim_ros.cli.tune`) is above it.
"""
