"""``tissue-sim bench BENCHMARK``: the command line of each benchmark, one module per benchmark.

``cli/bench/solver.py`` is ``tissue-sim bench solver``'s parser and ``run``, which calls
``bench.solver.run`` with plain keyword arguments; likewise for every benchmark (``material``
is bench/material_accuracy.py). One module each, rather than one cli/bench.py for all, because
``tissue-sim bench X`` imports only X's module (the COMMANDS table in cli/__init__.py names it):
the benchmarks' libraries pull in numba kernels, scikit-fem, ROS and optional peers, and one
benchmark's missing extra must not break another's command. It also keeps each command beside
the one library module it drives.

A benchmark's description (``tissue-sim bench X --help``) is its library module's docstring,
which says what it measures; the parser shows it as plain text.
"""
