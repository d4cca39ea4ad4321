"""Benchmarks: speed, accuracy and stability, each a function that takes its settings as plain
arguments, prints a table and writes a CSV and a chart (``tissue-sim bench NAME`` calls it).

Also the independent references they measure against: the exact Newton step
(``reference``), a plane-stress FEM with scikit-fem (``fem_reference``), a NumPy Jacobi
baseline, and optional peer simulators. May import the core, render, ros and experiments
layers, never the CLI; nothing below imports a benchmark.
"""
