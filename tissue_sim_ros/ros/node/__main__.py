"""``python -m tissue_sim_ros.ros.node``: the node without its console script (as ``tissue_sim_node``)."""
import sys

from . import main

sys.exit(main())
