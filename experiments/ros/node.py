"""The estimator as a live ROS 1 node (``scene-estimator ros``), through rospy.

**In.** The topics of a topics file (:mod:`experiments.ros.topics`, the same as ``run --bag
--topics``): ``tf2_msgs/TFMessage`` sources, ``geometry_msgs/PoseStamped`` sources, hands, several
sources fused by inverse variance; ``/tf`` and ``/tf_static`` are always read to chain poses to the
world frame (a moving camera through TF). Messages become frames exactly as a bag's do
(:class:`~experiments.ros.reader.FrameAssembler`): sorted within the topics file's ``reorder``
window (s of stamp time), grouped into frames by ``window``; a frame is closed once the time has
passed it by ``window + reorder``. The time is the newest stamp received plus the wall time since it
arrived (no clock needs to agree with the stamps; ``/clock`` is not needed). ``t = 0`` is the first
message's stamp.

Frames go into a :class:`~experiments.live.FrameQueue` and a :class:`~experiments.live.LiveLoop`
runs the estimator on them (``ros`` is always live: never more than one reasoning step behind, the
frames that arrived during a step merged into the next and counted).

**Out** (under the node's name, ``/scene_estimator/`` by default), per reasoning step, stamped with
the step's time (its newest frame's stamp): TF frames ``estimate/<id>`` (parent: the world frame);
``pose/<id>`` ``geometry_msgs/PoseWithCovarianceStamped`` (covariance:
:func:`~experiments.ros.uncertainty.pose_covariance`); ``markers`` ``visualization_msgs/MarkerArray``
(ellipsoids of the 90 % regions, a sphere and a label per hypothesis); ``estimate``
``std_msgs/String``: the estimate line of ``run --live`` (JSON with ``merged`` and ``latency``).
``diagnostics`` (``std_msgs/String``, latched, JSON): frames, steps, merged frames, restarts, the
latency (the last step's, the p95 of the last 100), the bad input counted, by kind and by topic, and
the last report, with a level and a message (:func:`~experiments.ros.publishers.health`: ``warn``
when frames were merged, bad input counted or the estimation restarted since the last report, or
when perception has been silent for ``silent_after`` s, or none came that long after subscribing);
the same as a ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` (status ``<node>: estimator``),
which ``rqt_robot_monitor`` shows, where Debian's ``python3-diagnostic-msgs`` is installed.

**Bad input** never stops the node; each is counted, reported on ``diagnostics`` and in the log
(stderr, with the topic and the field): ``non_finite`` (a NaN or infinite coordinate, a zero
quaternion: the transform or pose is dropped), ``unknown_frame`` (no TF chain to the world
frame), ``late`` (stamped before what has been released, i.e. more than ``reorder`` late: a late
transform or pose is dropped), ``time_backwards`` (stamped more than ``reset_after`` s before the
newest message: a bag replayed in a loop; the estimation *restarts* from that message: a new
estimator, ``t = 0`` there, the TF tree kept), ``wrong_type`` (a topic whose publisher sends another
message type than the topics file says: its messages are dropped), ``malformed`` (a message that
does not deserialise).

The bad input's counting and checks are in :mod:`experiments.ros.bad_input`, the messages published
in :mod:`experiments.ros.publishers`; this module holds the node (subscriptions, frame assembly, the
spin loop) and the ``ros`` command's entry point (:func:`run_node`).
"""
from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from experiments.live import TIMELINE_WINDOW, FrameQueue, LiveLoop
from experiments.ros.assembler import FrameAssembler, decode_message
from experiments.ros.bad_input import ROS1_TYPES, BadInput, finite_part
from experiments.ros.publishers import LEVEL_NAMES, NodePublishers, health
from experiments.ros.topics import TF_STATIC_TOPIC, TF_TOPIC, TopicsSpec


@dataclass(frozen=True)
class NodeOptions:
    """How the node runs. ``name``: node name (outputs under ``/name/``); ``reset_after`` (s): a
    message stamped this much before the newest one restarts the estimation; ``timeline_window``
    (s, None: all): see :class:`~experiments.live.LiveLoop`; ``tick`` (s): how often the pending
    frame is checked for closing; ``report_first`` / ``report_every``: each (kind, topic) of bad
    input is logged the first ``report_first`` times, then every ``report_every``-th (all are
    counted); ``max_estimates``: stop after that many (None: run until shut down);
    ``diagnostics_period`` (s): how often ``diagnostics`` is published besides on change;
    ``silent_after`` (s): perception silent for longer than this (or none this long after the node
    subscribed) is a warning."""

    name: str = "scene_estimator"
    reset_after: float = 1.0
    timeline_window: float | None = TIMELINE_WINDOW
    tick: float = 0.005
    report_first: int = 10
    report_every: int = 100
    max_estimates: int | None = None
    diagnostics_period: float = 1.0
    silent_after: float = 2.0
    quiet: bool = False

    def __post_init__(self):
        if not self.reset_after > 0:
            raise ValueError(f"reset_after must be > 0 s, got {self.reset_after}")
        if not self.tick > 0:
            raise ValueError(f"tick must be > 0 s, got {self.tick}")
        if not self.silent_after > 0:
            raise ValueError(f"silent_after must be > 0 s, got {self.silent_after}")


class _StreamQueue(FrameQueue):
    """The frames of one stream (from the start, or since a restart); ``t0_ns``: its ``t = 0``."""

    t0_ns: int | None = None


class RosNode:
    """Subscriptions, the frame assembly, the live loop and the publishers (see the module
    docstring). ``ros``: :func:`~experiments.ros.rospy_env.import_ros`'s modules; the node must be
    initialised (``rospy.init_node``) before. :meth:`spin` runs until ROS shuts down (or
    ``options.max_estimates``)."""

    def __init__(self, ros, scene, topics: TopicsSpec, config, seed: int, options: NodeOptions = NodeOptions()):
        self.ros = ros
        self.scene, self.topics, self.config, self.seed, self.options = scene, topics, config, seed, options
        rospy = ros.rospy
        self.callerid = rospy.get_name()
        self.bad = BadInput(rospy.logwarn, options.report_first, options.report_every)
        self._lock = threading.Lock()
        self.queue = _StreamQueue()
        self.assembler = self._new_assembler()
        self._newest_wall: float | None = None
        self._seq = 0
        self.resets = 0
        self.frames = self.steps = self.merged = self.estimates = 0
        self.latencies: list[float] = []
        self._last_diagnostics: dict | None = None
        self._subscribed_wall: float | None = None
        self._stop = threading.Event()
        self._dynamic = [oid for oid in scene.object_ids]
        self.publishers = NodePublishers(ros, scene.object_ids, topics.world_frame)
        self._subs = []
        self._pump = threading.Thread(target=self._pump_loop, name="frame-closer", daemon=True)

    def _subscribe(self) -> None:
        """Subscribe to the sources, ``/tf`` and ``/tf_static`` (once the estimator is built: a
        publisher that waits for the node's subscriptions finds it ready)."""
        rospy, topics = self.ros.rospy, self.topics
        tf_sources = {s.topic for s in topics.sources if s.type == "tf"}
        for i, src in enumerate(topics.sources):
            self._subs.append(rospy.Subscriber(src.topic, rospy.AnyMsg, self._on_message, (i, src.topic, src.type),
                                               queue_size=100))
        if TF_TOPIC not in tf_sources:
            self._subs.append(rospy.Subscriber(TF_TOPIC, rospy.AnyMsg, self._on_message, (-1, TF_TOPIC, "tf"),
                                               queue_size=100))
        self._subs.append(rospy.Subscriber(TF_STATIC_TOPIC, rospy.AnyMsg, self._on_message,
                                           (-2, TF_STATIC_TOPIC, "tf"), queue_size=100))
        self._subscribed_wall = time.monotonic()
        self._pump.start()

    # -- in ---------------------------------------------------------------------------------------

    def _new_assembler(self) -> FrameAssembler:
        return FrameAssembler(self.topics, 0, self._report)

    def _report(self, kind: str, topic: str, message: str) -> None:
        self.bad(kind, topic, "header.stamp" if kind == "late" else "", message)

    def _on_message(self, raw, args) -> None:
        index, topic, kind = args
        header = getattr(raw, "_connection_header", None) or {}
        if header.get("callerid") == self.callerid:
            return  # our own estimate/<id> frames on /tf
        expected = ROS1_TYPES[kind]
        got = header.get("type", "?")
        if got != expected:
            where = f"sources[{index}].type" if index >= 0 else "the TF topics"
            self.bad("wrong_type", topic, "", f"carries {got}, not {expected} ({where} in the topics file says "
                                              f"{kind}); message dropped")
            return
        cls = self.ros.tf2_msgs.TFMessage if kind == "tf" else self.ros.geometry_msgs.PoseStamped
        try:
            msg = cls().deserialize(raw._buff)
        except Exception as exc:  # genpy raises several types for a short or garbled buffer
            self.bad("malformed", topic, "", f"cannot deserialise a {expected}: {type(exc).__name__}: {exc}")
            return
        msg = finite_part(msg, kind, topic, self.bad)
        if msg is None:
            return
        try:
            self._take(msg, index, topic, kind)
        except Exception as exc:  # never let a message stop the subscriber thread
            self.bad("malformed", topic, "", f"{type(exc).__name__}: {exc}")

    def _take(self, msg, index: int, topic: str, kind: str) -> None:
        with self._lock:
            asm = self.assembler
            if index == -2:  # static transforms place frames for good
                for parent, child, pose in decode_message(msg, True, topic, -1, 0).transforms:
                    asm.tf.set(parent, child, pose)
                return
            self._seq += 1
            item = decode_message(msg, kind == "tf", topic, max(index, -1), self._seq)
            if item.kind == "tf" and not item.transforms:
                return
            if self.queue.t0_ns is None:
                self.queue.t0_ns = asm.t0_ns = item.stamp_ns
            elif item.stamp_ns < asm.newest - self.options.reset_after * 1e9:
                self._restart(item, asm)
                asm = self.assembler
            if item.stamp_ns > asm.newest:
                self._newest_wall = time.monotonic()
            for frame in asm.push(item):
                self.queue.put(frame)

    def _restart(self, item, old: FrameAssembler) -> None:
        """Time went backwards: a new stream from ``item`` (the live loop restarts the estimator)."""
        back = (old.newest - item.stamp_ns) / 1e9
        self.bad("time_backwards", item.topic, "header.stamp",
                 f"stamped {back:.2f} s before the newest message (more than reset_after = "
                 f"{self.options.reset_after} s: a bag replayed in a loop, /clock jumped back); the estimation "
                 f"restarts from this message")
        self.resets += 1
        asm = self._new_assembler()
        asm.tf = old.tf  # static transforms and the latest of each edge are kept
        asm.t0_ns = item.stamp_ns
        previous, self.queue = self.queue, _StreamQueue()
        self.queue.t0_ns = item.stamp_ns
        self.assembler = asm
        previous.close()

    def _pump_loop(self) -> None:
        """Close pending frames as time passes (the newest stamp plus the wall time since it came)."""
        while not self._stop.wait(self.options.tick):
            with self._lock:
                asm = self.assembler
                if self._newest_wall is None or asm.newest == -math.inf:
                    continue
                now = asm.newest + int((time.monotonic() - self._newest_wall) * 1e9)
                for frame in asm.advance(now):
                    self.queue.put(frame)

    # -- the loop ---------------------------------------------------------------------------------

    def spin(self) -> dict:
        """Run the live loop until ROS shuts down (or ``max_estimates``); returns a summary."""
        from estimator.filter import SceneEstimator

        rospy = self.ros.rospy
        est = loop = None
        last_diag, diag_version = 0.0, -1
        try:
            est = SceneEstimator(self.scene, self.config, np.random.default_rng(self.seed))
            loop = LiveLoop(est, self.queue, timeline_window=self.options.timeline_window)
            self._subscribe()
            while not rospy.is_shutdown() and not self._stop.is_set():
                queue = self.queue
                if loop is None or loop.queue is not queue:
                    if loop is not None:
                        self._count(loop)
                        est.close()
                    est = SceneEstimator(self.scene, self.config, np.random.default_rng(self.seed))
                    loop = LiveLoop(est, queue, timeline_window=self.options.timeline_window)
                step = loop.poll(timeout=0.05)
                if step is not None:
                    self._publish(step, queue.t0_ns)
                    if self.options.max_estimates is not None and self.estimates >= self.options.max_estimates:
                        break
                now = time.monotonic()
                if self.bad.version != diag_version or now - last_diag >= self.options.diagnostics_period:
                    diag_version = self.bad.version
                    last_diag = now
                    self._publish_diagnostics(loop)
        finally:
            self._stop.set()
            for s in self._subs:
                s.unregister()
            if loop is not None:
                self._count(loop)
                self._publish_diagnostics(None)
            if est is not None:
                est.close()
        return self.summary()

    def _count(self, loop: LiveLoop) -> None:
        self.frames += loop.frames
        self.steps += loop.steps
        self.merged += loop.merged

    def summary(self) -> dict:
        lat = np.asarray(self.latencies) if self.latencies else None
        return {"frames": self.frames, "steps": self.steps, "estimates": self.estimates, "merged": self.merged,
                "restarts": self.resets, "bad": self.bad.to_json(),
                "latency_s_median": float(np.median(lat)) if lat is not None else None,
                "latency_s_max": float(lat.max()) if lat is not None else None}

    def _publish_diagnostics(self, loop: LiveLoop | None) -> None:
        live = {"frames": self.frames + (loop.frames if loop else 0), "steps": self.steps + (loop.steps if loop else 0),
                "merged": self.merged + (loop.merged if loop else 0)}
        recent = 1e3 * np.asarray(self.latencies[-100:])
        doc = {"node": self.callerid, "particles": loop.estimator.K if loop else self.config.particles,
               "seed": self.seed,
               "ready": bool(self._subs), **live, "estimates": self.estimates, "restarts": self.resets,
               "latency_ms_last": round(float(recent[-1]), 1) if len(recent) else None,
               "latency_ms_p95": round(float(np.percentile(recent, 95)), 1) if len(recent) else None,
               "bad": self.bad.to_json()}
        since = self._newest_wall if self._newest_wall is not None else self._subscribed_wall
        silent = None if since is None else time.monotonic() - since
        level, doc["message"] = health(doc, self._last_diagnostics, silent, self.options.silent_after)
        doc["level"] = LEVEL_NAMES[level]
        self._last_diagnostics = doc
        self.publishers.diagnostics(doc)

    # -- out --------------------------------------------------------------------------------------

    def _publish(self, step, t0_ns: int | None) -> None:
        self.publishers.estimate(step, t0_ns)
        self.estimates += 1
        self.latencies.append(step.latency)
        if len(self.latencies) > 10000:
            del self.latencies[:5000]


# -- the command ------------------------------------------------------------------------------------

def _wait_for_master(ros, timeout: float, quiet: bool) -> None:
    uri = ros.rosgraph.get_master_uri()
    deadline = time.monotonic() + timeout
    said = False
    while not ros.rosgraph.is_master_online():
        if time.monotonic() >= deadline:
            raise ValueError(f"no ROS master at {uri} (ROS_MASTER_URI) after {timeout:g} s: start one with "
                             f"`roscore`, or point ROS_MASTER_URI at it")
        if not said and not quiet:
            print(f"waiting for the ROS master at {uri} ...", file=sys.stderr, flush=True)
            said = True
        time.sleep(0.2)


def _parameters(rospy, args) -> None:
    """Fill the options the command line left out from the node's private parameters (``~name``)."""
    from experiments.ros.parameters import PARAMETERS

    for name in PARAMETERS:
        if getattr(args, name, None) is None and rospy.has_param("~" + name):
            value = rospy.get_param("~" + name)
            setattr(args, name, value)


def run_node(args, ros) -> int:
    """``scene-estimator ros``: wait for the master, start the node, run until shut down."""
    from experiments.cli.common import build_config, live_config
    from experiments.ros.topics import default_topics, load_topics
    from experiments.streams import StopSignals, Terminated
    from physics.scene import load_scene

    rospy = ros.rospy
    _wait_for_master(ros, args.master_timeout, args.quiet)
    rospy.init_node(args.name, anonymous=False, disable_signals=True)
    _parameters(rospy, args)
    if not args.scene:
        raise ValueError("--scene: missing (give --scene FILE or set the ~scene parameter)")
    if args.seed is None:
        args.seed = 0
    scene = load_scene(str(args.scene))
    topics = (load_topics(str(args.topics), scene.object_ids, args.world_frame) if args.topics
              else default_topics(scene.object_ids, args.world_frame or "world"))
    config = live_config(build_config(args), True, args.fixed_particles)
    options = NodeOptions(name=args.name, reset_after=1.0 if args.reset_after is None else float(args.reset_after),
                          silent_after=2.0 if args.silent_after is None else float(args.silent_after),
                          timeline_window=(TIMELINE_WINDOW if args.timeline_window is None
                                           else float(args.timeline_window)),
                          max_estimates=args.max_estimates, quiet=args.quiet)
    if ros.diagnostic_msgs is None:
        rospy.logwarn("diagnostic_msgs is not installed (Debian package python3-diagnostic-msgs): the status is "
                      "published on ~diagnostics (JSON) only, not on /diagnostics")
    with StopSignals() as signals:
        node = RosNode(ros, scene, topics, config, int(args.seed), options)
        if not args.quiet:
            print(f"{rospy.get_name()}: K={config.particles}, {len(topics.sources)} source(s) "
                  f"({', '.join(s.topic for s in topics.sources)}), world frame {topics.world_frame!r}; publishing "
                  f"{rospy.get_name()}/estimate, /pose/<id>, /markers, /diagnostics (JSON), TF estimate/<id>, and "
                  f"its status on the global /diagnostics",
                  file=sys.stderr, flush=True)
        try:
            summary = node.spin()
        except (KeyboardInterrupt, Terminated) as exc:  # how roslaunch and systemd stop a node: a normal end
            summary = node.summary()
            if not args.quiet:
                print(f"{type(exc).__name__ if isinstance(exc, Terminated) else 'SIGINT'}: shutting down",
                      file=sys.stderr)
        finally:
            with signals.deferred():
                rospy.signal_shutdown("scene-estimator ros ended")
    if not args.quiet:
        med = summary["latency_s_median"]
        bad = summary["bad"]
        print(f"{summary['frames']} frames, {summary['estimates']} estimates, {summary['merged']} frame(s) merged, "
              f"{summary['restarts']} restart(s); latency median "
              f"{1e3 * med if med is not None else float('nan'):.0f} ms; bad input: {bad['total']} "
              f"({', '.join(f'{k} {v}' for k, v in bad['counts'].items() if v) or 'none'})", file=sys.stderr)
    return 0
