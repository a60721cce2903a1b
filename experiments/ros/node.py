"""The live ROS 1 node of ``scene-estimator ros`` (being written)."""
from __future__ import annotations

import sys


def run_node(args, ros) -> int:
    print("error: the ROS node is not implemented yet", file=sys.stderr)
    return 2
