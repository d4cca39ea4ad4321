"""Runnable experiments: the paper's experiments a and b, the demo (node, recorder and tool
driver as separate processes), insertion planning offline and against a live node, and
fitting a material to a recording.

Each takes a :class:`~tissue_sim_ros.core.config.Config` and plain arguments, writes its
figures and data, and returns a result; the ``tissue-sim`` command (:mod:`tissue_sim_ros.cli`)
parses the command line and calls them. May import the core, render and ros layers.
"""
