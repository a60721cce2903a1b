"""``scene-estimator bench --scenario NAME --bag``: the same stream read from JSON Lines and from a ROS bag.

A scenario's observation frames are written twice: as the JSONL file ``scene-estimator run`` reads,
and as a ROS 2 bag from two sources, as a robot would record them: a tracker publishing every
detection as a ``/tf`` transform ``world -> <object id>`` (hands as ``world -> hand_<i>``), and a
motion-capture system publishing the same detections as ``geometry_msgs/PoseStamped`` on
``/mocap/<object id>`` (fused by their noise on reading, so the positions are the JSONL's). Each is
then run through a new estimator the way ``scene-estimator run`` does, reading included, and the
wall times are compared (``bag_over_jsonl``).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from estimator.filter import SceneEstimator
from estimator.observations import Frame, ObservationReader, write_observations
from experiments.ros.reader import BagFrameReader
from experiments.ros.topics import load_topics
from experiments.ros.writer import pose_stamped, transform_stamped

NS = 1_000_000_000

BAG_COLUMNS = [("scenario", "scenario", "{}"), ("particles", "K", "{}"), ("frames", "frames", "{}"),
               ("jsonl_s", "JSONL run (s)", "{:.2f}"), ("bag_s", "bag run (s)", "{:.2f}"),
               ("bag_over_jsonl", "bag / JSONL", "{:.2f}")]


def write_two_source_bag(frames: list[Frame], folder: str, position_std: float = 0.01) -> tuple[str, str]:
    """Write ``frames`` as a ROS 2 bag (folder ``folder/bag``) from two sources (see the module
    docstring) and the topics file that reads it (``folder/topics.yaml``); returns both paths. Each
    source has noise ``position_std`` (m)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    ids = sorted({oid for f in frames for oid in f.objects})
    hands = sorted({h for f in frames for h in f.hands})
    bag = os.path.join(folder, "bag")

    with Writer(Path(bag), version=8) as w:
        tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        mocap = {oid: w.add_connection(f"/mocap/{oid}", "geometry_msgs/msg/PoseStamped", typestore=ts)
                 for oid in ids}
        for f in frames:
            ns = int(round(f.t * NS))
            edges = [transform_stamped(T, ns, "world", oid, d.position, _orientation(d))
                     for oid, d in f.objects.items()]
            edges += [transform_stamped(T, ns, "world", f"hand_{hands.index(h)}", p, (0, 0, 0, 1))
                      for h, p in f.hands.items()]
            if edges:
                msg = T["tf2_msgs/msg/TFMessage"](transforms=edges)
                w.write(tf, ns, ts.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
            for oid, d in f.objects.items():
                pose = pose_stamped(T, ns, "world", d.position, _orientation(d))
                w.write(mocap[oid], ns, ts.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped"))
    lines = ["world_frame: world", "window: 0", "sources:",
             "  - topic: /tf", "    type: tf", "    objects: {" + ", ".join(f"{o}: {o}" for o in ids) + "}",
             f"    position_std: {position_std}"]
    for oid in ids:
        lines += [f"  - topic: /mocap/{oid}", "    type: pose", f"    object: {oid}", f"    position_std: {position_std}"]
    if hands:
        lines.append("hands: {" + ", ".join(f"hand_{i}: '{h}'" for i, h in enumerate(hands)) + "}")
    topics = os.path.join(folder, "topics.yaml")
    Path(topics).write_text("\n".join(lines) + "\n")
    return bag, topics


def _orientation(d) -> tuple:
    return tuple(d.orientation) if d.orientation is not None else (0.0, 0.0, 0.0, 1.0)


def _timed_run(scene, cfg, frames_iter) -> float:
    """Wall time (s) of reading ``frames_iter`` and updating a new estimator with every frame."""
    t0 = time.perf_counter()
    with SceneEstimator(scene, cfg, np.random.default_rng(0)) as est:
        for f in frames_iter:
            est.update(f)
    return time.perf_counter() - t0


def bag_rows(name: str, scene, frames: list[Frame], configs):
    """Rows of :data:`BAG_COLUMNS` for one scenario's stream and each ``(K, config)``."""
    with tempfile.TemporaryDirectory(prefix="bagbench_") as tmp:
        jsonl = os.path.join(tmp, "observations.jsonl")
        write_observations(jsonl, frames)
        bag, topics = write_two_source_bag(frames, tmp)
        spec = load_topics(topics, scene.object_ids)
        for k, cfg in configs:
            print(f"bench: {name}, K={k}: JSONL and a two-source bag", file=sys.stderr, flush=True)
            j = _timed_run(scene, cfg, ObservationReader(jsonl, scene.object_ids))
            b = _timed_run(scene, cfg, BagFrameReader(bag, spec))
            yield {"scenario": name, "particles": k, "frames": len(frames), "jsonl_s": j, "bag_s": b,
                   "bag_over_jsonl": b / j}
