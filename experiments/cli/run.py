"""``run`` (estimate a recorded stream, JSONL or ROS bag) and ``config`` (the configuration ``run``
would use)."""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np

from estimator.config import EstimatorConfig, config_to_dict
from estimator.filter import SceneEstimator
from estimator.observations import ObservationReader
from experiments.cli.common import add_estimator_arguments, build_config, print_summary
from physics.scene import load_scene


@dataclasses.dataclass(frozen=True)
class BagInput:
    """Perception read from a ROS bag instead of a JSONL stream (``run --bag``).

    ``path``: ROS 1 ``.bag`` file or ROS 2 bag folder; ``topics``: topics file (``None``: ``/tf`` and
    ``/tf_static``, child frames named like scene objects); ``world_frame``: the scene's frame (wins
    over the topics file's; default ``world``); ``out``: bag to write the estimates to (``.bag``:
    ROS 1, otherwise a ROS 2 folder)."""

    path: str
    topics: str | None = None
    world_frame: str | None = None
    out: str | None = None


def _frame_reader(scene, observations_path: str | None, bag: BagInput | None, skip_bad_frames: bool, warn):
    """The frames of a JSONL stream or of a bag: an iterable with ``frames_read`` and ``skipped``."""
    if (observations_path is None) == (bag is None):
        raise ValueError("give exactly one of an observation stream (--observations) and a bag (--bag)")
    if bag is None:
        return ObservationReader(observations_path, scene.object_ids, skip_bad_frames=skip_bad_frames, warn=warn)
    from experiments.ros.reader import BagFrameReader
    from experiments.ros.topics import default_topics, load_topics

    topics = (load_topics(bag.topics, scene.object_ids, bag.world_frame) if bag.topics
              else default_topics(scene.object_ids, bag.world_frame or "world"))
    return BagFrameReader(bag.path, topics, skip_bad_frames=skip_bad_frames, warn=warn)


def run_stream(scene_path: str, observations_path: str | None, config: EstimatorConfig, seed: int,
               out_path: str | None, timeline_path: str | None, skip_bad_frames: bool = False,
               quiet: bool = False, on_belief=None, on_frame=None, bag: BagInput | None = None) -> dict:
    """Estimate a whole observation stream (a JSONL file, or a ROS bag given as ``bag`` with
    ``observations_path=None``), writing one estimate line per reasoning step as it goes
    (flushed, so an interrupted run keeps what it wrote), the estimates also into ``bag.out`` when
    given, and the timeline at the end (also on interruption). ``on_frame(frame)`` and
    ``on_belief(belief)`` see every frame and every belief. Returns a summary dict."""
    scene = load_scene(scene_path)
    warnings: list[str] = []

    def warn(msg: str) -> None:
        warnings.append(msg)
        if not quiet:
            print(f"warning: {msg}", file=sys.stderr)

    reader = _frame_reader(scene, observations_path, bag, skip_bad_frames, warn)
    bag_out = None
    if bag is not None and bag.out:
        from experiments.ros.writer import BagEstimateWriter
        bag_out = BagEstimateWriter(bag.out, reader.topics.world_frame, reader.t0_ns)
    out = open(out_path, "w", encoding="utf-8") if out_path else None
    n_est = 0
    times = []
    t_start = time.perf_counter()
    est = SceneEstimator(scene, config, np.random.default_rng(seed))
    try:
        for frame in reader:
            if on_frame is not None:
                on_frame(frame)
            t0 = time.perf_counter()
            belief = est.update(frame)
            if belief is None:
                continue
            times.append(time.perf_counter() - t0)
            n_est += 1
            line = belief.to_json()
            if out is not None:
                out.write(json.dumps(line) + "\n")
                out.flush()
            if bag_out is not None:
                bag_out.write(line)
            if on_belief is not None:
                on_belief(belief)
    finally:
        est.close()
        if out is not None:
            out.close()
        if bag_out is not None:
            bag_out.close()
        if timeline_path:
            est.timeline.write(timeline_path)
    return {"frames": reader.frames_read, "skipped": reader.skipped, "estimates": n_est,
            "seconds": time.perf_counter() - t_start,
            "update_ms_median": 1e3 * float(np.median(times)) if times else None,
            "timeline": est.timeline.to_json(), "last_belief": est.last_belief,
            "recoveries": est.recoveries, "rejected": est.rejected_detections,
            "reseeded": est.reseeded, "worker_restarts": est.pool.restarts,
            "late": getattr(reader, "late", 0)}


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``run``."""
    p.add_argument("--scene", required=True, help="scene file (YAML or JSON)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--observations", help="observation stream (JSON Lines)")
    src.add_argument("--bag", help="perception from a ROS 1 bag (.bag) or a ROS 2 bag (folder) instead")
    p.add_argument("--topics", metavar="FILE",
                   help="with --bag: topics file (YAML) naming the sources (tf / pose topics, frame -> object, "
                        "position_std), hands and world frame; without it /tf and /tf_static are read and a "
                        "child frame named like a scene object is that object")
    p.add_argument("--world-frame", help="with --bag: the scene's TF frame (default: world, or the topics file's)")
    p.add_argument("--bag-out", metavar="PATH",
                   help="with --bag: also write the estimates to a bag (TF frames estimate/<id> and "
                        "/scene_estimator/estimate JSON strings); a path ending in .bag is a ROS 1 bag, "
                        "any other a ROS 2 bag folder")
    p.add_argument("--out", help="estimate stream to write (JSON Lines)")
    p.add_argument("--timeline", help="timeline to write at the end (JSON)")
    add_estimator_arguments(p)
    p.add_argument("--rerun", metavar="PATH", help="also write a rerun recording (.rrd); open it with `rerun PATH`")
    p.add_argument("--skip-bad-frames", action="store_true",
                   help="drop malformed frames with a counted warning instead of stopping")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def cmd_run(args) -> int:
    bag = None
    if args.bag:
        bag = BagInput(args.bag, args.topics, args.world_frame, args.bag_out)
    else:
        for name in ("topics", "world_frame", "bag_out"):
            if getattr(args, name):
                raise ValueError(f"--{name.replace('_', '-')} needs --bag")
    recorder = None
    if args.rerun:
        from experiments.recording import Recorder
        recorder = Recorder(args.rerun, load_scene(args.scene))
    try:
        summary = run_stream(args.scene, args.observations, build_config(args), args.seed, args.out,
                             args.timeline, args.skip_bad_frames, args.quiet,
                             on_belief=recorder.log_belief if recorder else None,
                             on_frame=recorder.log_frame if recorder else None, bag=bag)
        if recorder is not None:
            recorder.log_timeline(summary["timeline"])
    finally:
        if recorder is not None:
            recorder.close()  # also on Ctrl-C: what was logged is kept
    if not args.quiet:
        print_summary(summary)
        if args.skip_bad_frames:
            print(f"\n{summary['skipped']} bad frame(s) skipped", file=sys.stderr)
        if summary["late"]:
            print(f"{summary['late']} bag message(s) too late to sort into place, dropped", file=sys.stderr)
    return 0


def cmd_config(args) -> int:
    """Print the effective estimator configuration (every field) as YAML, or JSON with --json."""
    cfg = build_config(args)
    data = config_to_dict(cfg)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        import yaml
        print(yaml.safe_dump(data, sort_keys=False, default_flow_style=None), end="")
    return 0
