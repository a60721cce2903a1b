"""``ros``: the estimator as a live ROS 1 node (:mod:`experiments.ros.node`).

ROS is an optional extra: this module imports nothing of ROS at import time; without rospy the
command exits 2 saying what to install (:mod:`experiments.ros.rospy_env`)."""
from __future__ import annotations

import argparse
import sys

from experiments.cli.common import add_estimator_arguments, add_fixed_particles_argument
from experiments.ros.parameters import PARAMETERS  # noqa: F401  (the options ~name may set)


def add_ros_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``ros``. Every option left out may come from the node's private parameters on the
    ROS parameter server (``~particles``, ``~seed``, ``~scene``, ``~topics``, ...; the command line wins)."""
    p.add_argument("--scene", help="scene file (YAML or JSON); or the ~scene parameter")
    p.add_argument("--topics", metavar="FILE",
                   help="topics file (YAML), the same as `run --bag --topics`: tf / pose sources, frame -> object, "
                        "position_std, hands, world frame, window, reorder; without it /tf is read and a child "
                        "frame named like a scene object is that object; or the ~topics parameter")
    p.add_argument("--world-frame", help="the scene's TF frame (default: world, or the topics file's)")
    add_estimator_arguments(p)
    p.set_defaults(seed=None)  # None: not given, so that ~seed can set it
    add_fixed_particles_argument(p, always_live=True)
    p.add_argument("--name", default="scene_estimator",
                   help="node name; the outputs are published under /NAME/ (default scene_estimator)")
    p.add_argument("--reset-after", metavar="SECONDS", type=float, default=None,
                   help="a message stamped this much before the newest one (a bag replayed in a loop: time "
                        "jumped back) restarts the estimation from it (default 1.0); smaller steps back are "
                        "late messages, dropped and counted")
    p.add_argument("--silent-after", metavar="SECONDS", type=float, default=None,
                   help="perception silent for longer than this, after some came, turns the /diagnostics "
                        "status to a warning (default 2.0)")
    p.add_argument("--timeline-window", metavar="SECONDS", type=float, default=None,
                   help="keep the timeline's facts and events of the last SECONDS of stream time (default 3600)")
    p.add_argument("--master-timeout", metavar="SECONDS", type=float, default=30.0,
                   help="wait this long for the ROS master ($ROS_MASTER_URI) before giving up (default 30)")
    p.add_argument("--max-estimates", metavar="N", type=int, default=None,
                   help="stop after N estimates (a test or a benchmark; default: run until shut down)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors and bad-input reports")


def run_ros(args) -> int:
    from experiments.ros.rospy_env import RosUnavailable, import_ros

    try:
        ros = import_ros()
    except RosUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from experiments.ros.node import run_node

    return run_node(args, ros)
