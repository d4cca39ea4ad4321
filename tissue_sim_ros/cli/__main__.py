"""``python -m tissue_sim_ros.cli``: the ``tissue-sim`` command."""
import sys

from . import main

sys.exit(main())
