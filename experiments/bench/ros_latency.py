"""End-to-end latency of the ROS node: a scenario's stream played into a real roscore at 30 Hz.

    python3 -m experiments.bench.ros_latency --scenario cup_carried_behind_box --particles 64 [--json]

One scenario per process (rospy initialises a process once). The scenario is simulated (seed 0); a ``roscore`` on a free port; the node started as a user
starts it (``scene-estimator ros --scene ... --topics ... --particles K``, a subprocess; default
workers); once it has subscribed (its particle worlds built), the stream is published at its real
rate as :class:`~experiments.ros.play.Player` does (a moving camera on ``/tf``, the objects as tags
seen by it, a ``PoseStamped`` tracker per object, hands; ``window`` 5 ms, ``reorder`` 10 ms), and
the node's ``pose/<id>`` messages are received in this process. Times are this process's
``time.monotonic`` (publisher and subscriber are the same process):

* ``latency_ms_*`` (median, p95, max): per frame published, from its publication to the reception
  of the first estimate stamped at or after it (the estimate that used it), through serialisation,
  the node's subscriber, the frame's closing, the live loop's step and the publication back;
* ``newest_latency_ms_p95``: per estimate, from the publication of its newest frame (the estimate's
  stamp) to its reception;
* ``frames``, ``estimates``, ``merged`` (frames folded into later steps), ``bad`` (bad input the node
  counted: late messages, mostly), from the node's ``diagnostics``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

SCENARIOS = ("cup_carried_behind_box", "ball_rolls_behind_box", "cup_falls_behind_box")
COLUMNS = [("scenario", "{}"), ("particles", "{}"), ("frames", "{}"), ("estimates", "{}"), ("merged", "{}"),
           ("bad", "{}"), ("latency_ms_median", "{:.1f}"), ("latency_ms_p95", "{:.1f}"), ("latency_ms_max", "{:.1f}"),
           ("newest_latency_ms_p95", "{:.1f}"), ("load_1min", "{:.2f}")]


def measure(ros, name: str, particles: int, workers: int | None, home: str) -> dict:
    """One row (module docstring) for scenario ``name`` at K = ``particles``."""
    from estimator.observations import ObservationReader
    from experiments.ros.play import Player, Roscore, topics_for
    from experiments.ros.publishers import topic_name
    from experiments.simulation.simulator import simulate, write_outputs
    from physics.scene import load_scene

    rospy = ros.rospy
    folder = os.path.join(home, name)
    os.makedirs(folder)
    paths = write_outputs(simulate(name, 0), folder)
    scene = load_scene(str(paths["scene.yaml"]))
    frames = list(ObservationReader(str(paths["observations.jsonl"]), scene.object_ids))
    seen = sorted({oid for f in frames for oid in f.objects})
    hands = sorted({h for f in frames for h in f.hands})
    topics = os.path.join(folder, "topics.yaml")
    with open(topics, "w") as fh:
        yaml.safe_dump(topics_for(seen, seen, hands), fh)
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    node_name = f"scene_estimator_{name}"
    with Roscore(ros, folder) as core:
        cmd = [sys.executable, "-m", "experiments.cli", "ros", "--scene", str(paths["scene.yaml"]), "--topics", topics,
               "--particles", str(particles), "--name", node_name, "--quiet"]
        if workers is not None:
            cmd += ["--workers", str(workers)]
        err = open(os.path.join(folder, "node.err"), "w")
        node = subprocess.Popen(cmd, cwd=root, env={**core.env, "PYTHONPATH": root}, stdout=subprocess.DEVNULL,
                                stderr=err)
        try:
            os.environ.update({k: core.env[k] for k in ("ROS_MASTER_URI", "ROS_HOME", "ROS_HOSTNAME")})
            rospy.init_node("ros_latency_bench", anonymous=True, disable_signals=True)  # once per process
            received: dict[int, float] = {}
            diagnostics: list[dict] = []
            watched = scene.object_ids[0]
            subs = [rospy.Subscriber(f"/{node_name}/pose/{topic_name(watched)}",
                                     ros.geometry_msgs.PoseWithCovarianceStamped,
                                     lambda m: received.setdefault(m.header.stamp.to_nsec(), time.monotonic())),
                    rospy.Subscriber(f"/{node_name}/diagnostics", ros.std_msgs.String,
                                     lambda m: diagnostics.append(json.loads(m.data)))]
            player = Player(ros, seen)
            player.wait_for(180)
            start = rospy.Time.now().to_nsec()
            player.publish_static(rospy.Time(nsecs=start))
            time.sleep(0.3)
            player.play(frames, start)
            last = start + int(round(frames[-1].t * 1e9))
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and (not received or max(received) < last):
                time.sleep(0.05)
            time.sleep(1.5)  # a diagnostics period
            for s in subs:
                s.unregister()
            for p in (player.tf, player.tf_static, *player.tracked.values()):
                p.unregister()
        finally:
            node.send_signal(2)
            try:
                node.wait(30)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()
            err.close()
    sent = player.sent
    est = sorted(received.items())
    stamps = np.array([s for s, _ in est])
    latencies = []
    for s, t_sent in sent.items():
        i = int(np.searchsorted(stamps, s))
        if i < len(est):
            latencies.append(est[i][1] - t_sent)
    newest = [t - sent[s] for s, t in est if s in sent]
    if not latencies:
        raise RuntimeError(f"{name}: no estimate received (see {folder}/node.err)")
    lat = 1e3 * np.asarray(latencies)
    diag = diagnostics[-1] if diagnostics else {}
    return {"scenario": name, "particles": particles, "frames": diag.get("frames", len(frames)),
            "estimates": len(est), "merged": diag.get("merged"), "bad": diag.get("bad", {}).get("total"),
            "latency_ms_median": float(np.median(lat)), "latency_ms_p95": float(np.percentile(lat, 95)),
            "latency_ms_max": float(lat.max()), "newest_latency_ms_p95": 1e3 * float(np.percentile(newest, 95)),
            "load_1min": os.getloadavg()[0], "bad_counts": diag.get("bad", {}).get("counts")}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python3 -m experiments.bench.ros_latency", description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default=SCENARIOS[0], help=f"a built-in scenario (default {SCENARIOS[0]})")
    p.add_argument("--particles", type=int, default=64, help="particle worlds K (default 64)")
    p.add_argument("--workers", type=int, default=None, help="the node's worker processes (default: one per core)")
    p.add_argument("--json", action="store_true", help="the row as JSON")
    args = p.parse_args(argv)
    from experiments.ros.rospy_env import RosUnavailable, import_ros

    try:
        ros = import_ros()
    except RosUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if shutil.which("roscore") is None:
        print("error: roscore is not on PATH (apt-get install ros-core)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="ros_latency_") as home:
        row = measure(ros, args.scenario, args.particles, args.workers, home)
    if args.json:
        print(json.dumps(row))
    else:
        for key, fmt in COLUMNS:
            value = row[key]
            print(f"{key:>24}: " + (fmt.format(value) if value is not None else "-"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
