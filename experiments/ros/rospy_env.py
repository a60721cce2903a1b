"""Finding ROS 1's Python packages (rospy and the message modules) for ``scene-estimator ros``.

Debian (bookworm) and Ubuntu package ROS 1 Noetic for their own Python 3 (``apt-get install
ros-core python3-rospy ...``): the modules land in ``/usr/lib/python3/dist-packages``, which a Python
built elsewhere (pyenv, a virtual environment) does not search. :func:`import_ros` first tries a
plain import and only when that fails installs an import hook (last on ``sys.meta_path``) that finds
*only* ROS's own top-level modules (:data:`ROS_MODULES`, any ``*_msgs`` / ``*_srvs``) and the few
pure dependencies this Python may lack (:data:`ROS_DEPENDENCIES`) in that directory (or in the
directories of ``$SCENE_ESTIMATOR_ROS_PATH``, separated by ``:``). The directory is not put on
``sys.path``: nothing else of Debian's (other modules, their entry points) becomes visible, and the
packages installed for this Python always win.

Nothing here is imported by the core install: only ``scene-estimator ros`` and its tests call
:func:`import_ros`.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import os
import sys
from types import SimpleNamespace

DIST_PACKAGES = ("/usr/lib/python3/dist-packages",)
"""Where Debian's and Ubuntu's ``python3-*`` packages install (searched when a plain import fails)."""
PATH_VARIABLE = "SCENE_ESTIMATOR_ROS_PATH"

#: module -> the Debian / Ubuntu package that provides it
PACKAGES = {
    "rospy": "python3-rospy",
    "rosgraph": "python3-rosgraph",
    "genpy": "python3-genpy",
    "tf2_ros": "python3-tf2-ros",
    "tf2_msgs.msg": "python3-tf2-msgs",
    "geometry_msgs.msg": "python3-geometry-msgs",
    "visualization_msgs.msg": "python3-visualization-msgs",
    "std_msgs.msg": "python3-std-msgs",
}
#: optional modules -> their package: without one, the node runs without what it serves
OPTIONAL_PACKAGES = {"diagnostic_msgs.msg": "python3-diagnostic-msgs"}
APT_PACKAGES = ("ros-core", "python3-rospy", "python3-tf2-ros", "python3-tf2-msgs", "python3-geometry-msgs",
                "python3-visualization-msgs", "python3-std-msgs", "python3-diagnostic-msgs")
INSTALL_COMMAND = "sudo apt-get install " + " ".join(APT_PACKAGES)
INSTALL_HINT = (f"install ROS 1 (Noetic) from Debian bookworm's or Ubuntu's packages: `{INSTALL_COMMAND}` "
                f"(they install into /usr/lib/python3/dist-packages, where their modules are found automatically; set "
                f"{PATH_VARIABLE}=DIR[:DIR] if they are elsewhere); this Python must be the same minor version "
                f"as the system's python3 (tf2_ros has a compiled part)")


class RosUnavailable(ImportError):
    """ROS 1's Python packages cannot be imported; the message says what to install."""


ROS_MODULES = frozenset({"rospy", "rosgraph", "genpy", "genmsg", "roslib", "rospkg", "catkin_pkg", "catkin", "roscpp",
                         "tf2_ros", "tf2_py", "actionlib", "message_filters", "rosbag", "roslz4", "rosmaster",
                         "rosparam", "rostopic", "rosnode", "rosservice", "rosmsg", "roslaunch"})
"""ROS 1's own top-level Python modules (with any name ending in ``_msgs`` or ``_srvs``)."""
ROS_DEPENDENCIES = frozenset({"distro", "defusedxml", "netifaces", "Cryptodome", "gnupg"})
"""Dependencies of rospkg, rosgraph and rosbag that a pip-installed Python often lacks; taken from
Debian's directory only when this Python has none of its own."""


def _search_dirs() -> list[str]:
    extra = [d for d in os.environ.get(PATH_VARIABLE, "").split(os.pathsep) if d]
    return extra + [d for d in DIST_PACKAGES if os.path.isdir(d)]


def _is_ros_module(name: str) -> bool:
    return name in ROS_MODULES or name in ROS_DEPENDENCIES or name.endswith(("_msgs", "_srvs"))


class DebianRosFinder(importlib.abc.MetaPathFinder):
    """Finds ROS's top-level modules (:func:`_is_ros_module`) in ``dirs``; asked last."""

    def __init__(self, dirs: list[str]):
        self.dirs = list(dirs)

    def find_spec(self, fullname, path=None, target=None):
        if path is not None or not _is_ros_module(fullname):
            return None  # submodules are found through their package's __path__
        return importlib.machinery.PathFinder.find_spec(fullname, self.dirs)


def _add_search_dirs() -> None:
    if not any(isinstance(f, DebianRosFinder) for f in sys.meta_path):
        sys.meta_path.append(DebianRosFinder(_search_dirs()))
    importlib.invalidate_caches()


def _import(name: str):
    """Module ``name``, imported as this Python finds it or else from Debian's directories
    (:func:`_add_search_dirs`); ImportError when neither has it."""
    try:
        return importlib.import_module(name)
    except ImportError:
        _add_search_dirs()
    return importlib.import_module(name)


def import_ros() -> SimpleNamespace:
    """Import rospy, rosgraph, tf2_ros and the message modules the node uses, adding Debian's
    dist-packages to the search path if a plain import fails. Returns them as attributes
    (``rospy``, ``rosgraph``, ``tf2_ros``, ``tf2_msgs``, ``geometry_msgs``, ``visualization_msgs``,
    ``std_msgs``: the ``.msg`` modules for the last four; ``diagnostic_msgs``, optional: None when
    its package is not installed). Raises :class:`RosUnavailable` naming the missing package and
    the command that installs it."""
    mods = {}
    for name, package in PACKAGES.items():
        try:
            mods[name] = _import(name)
        except ImportError as exc:
            found = any(os.path.exists(os.path.join(d, name.split(".")[0])) for d in _search_dirs())
            detail = (f"{name} is installed in {', '.join(_search_dirs())} but does not import into Python "
                      f"{sys.version.split()[0]} ({sys.executable}): {exc}" if found
                      else f"the Python module {name} (Debian package {package}) is not installed")
            raise RosUnavailable(f"ROS 1 is not available: {detail}. To run the ROS node, {INSTALL_HINT}.") from None
    for name in OPTIONAL_PACKAGES:
        try:
            mods[name] = _import(name)
        except ImportError:
            mods[name] = None
    return SimpleNamespace(rospy=mods["rospy"], rosgraph=mods["rosgraph"], genpy=mods["genpy"],
                           tf2_ros=mods["tf2_ros"], tf2_msgs=mods["tf2_msgs.msg"],
                           geometry_msgs=mods["geometry_msgs.msg"],
                           visualization_msgs=mods["visualization_msgs.msg"], std_msgs=mods["std_msgs.msg"],
                           diagnostic_msgs=mods["diagnostic_msgs.msg"])


def ros_available() -> tuple[bool, str]:
    """(True, "") when :func:`import_ros` works, else (False, the reason with what to install)."""
    try:
        import_ros()
    except RosUnavailable as exc:
        return False, str(exc)
    return True, ""
