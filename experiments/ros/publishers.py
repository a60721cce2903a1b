"""What the live ROS node (:mod:`experiments.ros.node`) publishes, under its name (``~``): per
reasoning step, stamped with the step's time, TF frames ``estimate/<id>`` (parent: the world
frame), ``pose/<id>`` ``geometry_msgs/PoseWithCovarianceStamped`` (the 6 x 6 covariance, row-major,
of :func:`~experiments.ros.uncertainty.pose_covariance`), ``markers``
``visualization_msgs/MarkerArray`` (ellipsoids of the :data:`REGION_LEVEL` regions, a sphere and a
label per hypothesis) and ``estimate`` ``std_msgs/String`` (the JSON estimate line); besides,
``diagnostics`` (``std_msgs/String``, latched, JSON) and the same as one
``diagnostic_msgs/DiagnosticStatus`` on ROS's :data:`DIAGNOSTICS_TOPIC`, its level from
:func:`health`. :func:`topic_name` makes an object id a ROS name. Units: metres, radians; stamps
from integer nanoseconds.
"""
from __future__ import annotations

import json
import re

import numpy as np

from experiments.ros.uncertainty import pose_covariance, region_ellipsoid

REGION_LEVEL = 0.9
DIAGNOSTICS_TOPIC = "/diagnostics"
"""ROS's diagnostics topic (``diagnostic_msgs/DiagnosticArray``), which ``rqt_robot_monitor`` and the
diagnostic aggregator read."""
OK, WARN = 0, 1
"""Levels of ``diagnostic_msgs/DiagnosticStatus`` that :func:`health` gives."""
LEVEL_NAMES = {OK: "ok", WARN: "warn"}
"""How the JSON report names each level."""
_LEVELS = {name: level for level, name in LEVEL_NAMES.items()}


def health(doc: dict, previous: dict | None, silent_s: float | None, silent_after: float) -> tuple[int, str]:
    """The level (:data:`OK` or :data:`WARN`) and message of the node's diagnostics document ``doc``
    (``frames``, ``estimates``, ``merged``, ``restarts``, ``particles``, ``bad``: ``total`` and
    ``last``), against the one published before it (``previous``; None: the first). WARN when, since
    then, frames were merged (the reasoning steps fall behind the frames), bad input was counted (the
    last report is quoted) or the estimation restarted (time went backwards); or when no perception
    came for more than ``silent_after`` s (``silent_s``: seconds since the newest message, or since
    the node subscribed while none has come; None: not subscribed yet). OK otherwise. Every reason
    that holds is in the message."""
    before = previous or {"merged": 0, "restarts": 0, "bad": {"total": 0}}
    reasons = []
    merged = doc["merged"] - before["merged"]
    if merged > 0:
        reasons.append(f"falling behind: {merged} frame(s) merged into later steps")
    bad = doc["bad"]["total"] - before["bad"]["total"]
    if bad > 0:
        reasons.append(f"{bad} bad input(s), the last: {doc['bad']['last']}")
    if doc["restarts"] > before["restarts"]:
        reasons.append("the estimation restarted: time went backwards")
    if silent_s is not None and silent_s > silent_after:
        reasons.append(f"no perception for {silent_s:.1f} s" if doc["frames"] > 0
                       else f"no perception yet, {silent_s:.1f} s after subscribing")
    if reasons:
        return WARN, "; ".join(reasons)
    if doc["frames"] == 0:
        return OK, "waiting for perception"
    return OK, f"estimating: {doc['estimates']} estimate(s), K = {doc['particles']}"


def topic_name(object_id: str) -> str:
    """A valid ROS name for an object id (letters, digits, ``_``; starting with a letter)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", object_id)
    return name if name[:1].isalpha() else "o_" + name


class NodePublishers:
    """The node's publishers and TF broadcaster, for the objects ``object_ids`` in the frame ``world``
    (``ros``: :func:`~experiments.ros.rospy_env.import_ros`'s modules; the node must be initialised
    (``rospy.init_node``) before)."""

    def __init__(self, ros, object_ids, world: str):
        self.ros = ros
        self.world = world
        rospy = ros.rospy
        ns = "~"
        self.pub_estimate = rospy.Publisher(ns + "estimate", ros.std_msgs.String, queue_size=10)
        self.pub_markers = rospy.Publisher(ns + "markers", ros.visualization_msgs.MarkerArray, queue_size=10)
        self.pub_diag = rospy.Publisher(ns + "diagnostics", ros.std_msgs.String, queue_size=10, latch=True)
        self.pub_status = (None if ros.diagnostic_msgs is None else
                           rospy.Publisher(DIAGNOSTICS_TOPIC, ros.diagnostic_msgs.DiagnosticArray, queue_size=10))
        self.status_name = rospy.get_name().lstrip("/") + ": estimator"
        self.pub_pose = {oid: rospy.Publisher(f"{ns}pose/{topic_name(oid)}", ros.geometry_msgs.PoseWithCovarianceStamped,
                                              queue_size=10) for oid in object_ids}
        self.tf_broadcaster = ros.tf2_ros.TransformBroadcaster()

    def diagnostics(self, doc: dict) -> None:
        """Publish the diagnostics document ``doc`` (JSON) on ``diagnostics`` and, with its ``level``
        (``"ok"`` or ``"warn"``) and ``message``, as the status ``<node>: estimator`` on
        :data:`DIAGNOSTICS_TOPIC` (the counts as key-value pairs; bad input per kind as ``bad_<kind>``)."""
        self.pub_diag.publish(self.ros.std_msgs.String(data=json.dumps(doc)))
        if self.pub_status is None:
            return
        dm = self.ros.diagnostic_msgs
        status = dm.DiagnosticStatus()
        status.level = _LEVELS[doc["level"]]
        status.name, status.message, status.hardware_id = self.status_name, doc["message"], doc["node"].lstrip("/")
        values = [(k, doc[k]) for k in ("frames", "steps", "estimates", "merged", "restarts", "particles", "seed",
                                        "latency_ms_last", "latency_ms_p95")]
        values += [("bad_total", doc["bad"]["total"])] + [(f"bad_{k}", n) for k, n in doc["bad"]["counts"].items()]
        status.values = [dm.KeyValue(key=k, value="" if v is None else str(v)) for k, v in values]
        array = dm.DiagnosticArray()
        array.header.stamp = self.ros.rospy.Time.now()
        array.status = [status]
        self.pub_status.publish(array)

    def estimate(self, step, t0_ns: int | None) -> None:
        """Publish a reasoning ``step`` (TF, poses, markers, the estimate line), stamped with
        ``t0_ns`` (ns of the stream's ``t = 0``; None: stamp 0) plus its belief's ``t``."""
        ros, rospy = self.ros, self.ros.rospy
        belief = step.belief
        stamp = rospy.Time(nsecs=0) if t0_ns is None else _time(rospy, t0_ns + int(round(belief.t * 1e9)))
        world = self.world
        gm = ros.geometry_msgs
        line = belief.to_json()
        line.update({"merged": step.merged, "latency": round(step.latency, 4)})
        transforms = []
        for oid, ob in belief.objects.items():
            pos, q = [float(v) for v in ob.position], [float(v) for v in ob.orientation]
            t = gm.TransformStamped()
            t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, world, f"estimate/{oid}"
            t.transform.translation = gm.Vector3(*pos)
            t.transform.rotation = gm.Quaternion(*q)
            transforms.append(t)
            msg = gm.PoseWithCovarianceStamped()
            msg.header.stamp, msg.header.frame_id = stamp, world
            msg.pose.pose.position = gm.Point(*pos)
            msg.pose.pose.orientation = gm.Quaternion(*q)
            msg.pose.covariance = [float(v) for v in self._covariance(belief, oid, ob).ravel()]
            self.pub_pose[oid].publish(msg)
        if transforms:
            self.tf_broadcaster.sendTransform(transforms)
        self.pub_markers.publish(self._markers(belief, stamp, world))
        self.pub_estimate.publish(ros.std_msgs.String(data=json.dumps(line)))

    @staticmethod
    def _covariance(belief, oid: str, ob) -> np.ndarray:
        parts = weights = None
        if belief.particles is not None and oid in belief.object_ids and ob.hypotheses:
            m = belief.object_ids.index(oid)
            parts, weights = belief.particles[:, m], belief.weights
        return pose_covariance(ob.position_cov, ob.orientation, parts, weights)

    def _markers(self, belief, stamp, world: str):
        vm, gm = self.ros.visualization_msgs, self.ros.geometry_msgs
        M = vm.Marker
        out = vm.MarkerArray()
        clear = M()
        clear.header.stamp, clear.header.frame_id, clear.action = stamp, world, 3  # DELETEALL
        out.markers.append(clear)
        for m, oid in enumerate(belief.object_ids):
            ob = belief.objects.get(oid)
            if ob is None or not ob.hypotheses:
                continue  # static objects: no region, no hypotheses
            color = _COLORS[m % len(_COLORS)]
            quat, scale = region_ellipsoid(ob.position_cov, ob.region(REGION_LEVEL))
            region = M()
            region.header.stamp, region.header.frame_id = stamp, world
            region.ns, region.id, region.type, region.action = "region_90", m, M.SPHERE, M.ADD
            region.pose.position = gm.Point(*[float(v) for v in ob.position])
            region.pose.orientation = gm.Quaternion(*[float(v) for v in quat])
            region.scale = gm.Vector3(*[float(v) for v in scale])
            region.color.r, region.color.g, region.color.b, region.color.a = *color, 0.35
            region.text = oid
            out.markers.append(region)
            for h_i, h in enumerate(ob.hypotheses):
                dot = M()
                dot.header.stamp, dot.header.frame_id = stamp, world
                dot.ns, dot.id, dot.type, dot.action = "hypotheses", 100 * m + h_i, M.SPHERE, M.ADD
                dot.pose.position = gm.Point(*[float(v) for v in h.position])
                dot.pose.orientation.w = 1.0
                dot.scale = gm.Vector3(0.02, 0.02, 0.02)
                dot.color.r, dot.color.g, dot.color.b, dot.color.a = *color, max(0.15, float(h.p))
                label = f"{oid}: {h.relation}" + (f" {h.support}" if h.support else "") + f" {h.p:.2f}"
                dot.text = label
                text = M()
                text.header.stamp, text.header.frame_id = stamp, world
                text.ns, text.id, text.type, text.action = "labels", 100 * m + h_i, M.TEXT_VIEW_FACING, M.ADD
                text.pose.position = gm.Point(float(h.position[0]), float(h.position[1]), float(h.position[2]) + 0.04)
                text.pose.orientation.w = 1.0
                text.scale.z = 0.025
                text.color.r = text.color.g = text.color.b = text.color.a = 1.0
                text.text = label
                out.markers.extend([dot, text])
        return out


_COLORS = [(0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16), (0.58, 0.4, 0.74),
           (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5), (0.74, 0.74, 0.13), (0.09, 0.75, 0.81)]


def _time(rospy, ns: int):
    return rospy.Time(secs=ns // 1_000_000_000, nsecs=ns % 1_000_000_000)
