"""The ``scene-estimator`` command line.

Subcommands: ``run`` (estimate a recorded stream), ``config`` (the configuration ``run`` would use),
``demo`` (the built-in example), ``simulate``
(scenario simulator), ``evaluate`` (statistics over scenarios, seeds and methods), ``bench`` (speed
against bare pybullet stepping), ``track`` (a Kalman pose tracker, fed back by the estimator),
``search`` (where to look first for a hidden object).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import time

import numpy as np

from estimator.config import (EstimatorConfig, ReasonerConfig, config_from_dict, config_to_dict, default_config,
                              read_config_file)
from estimator.filter import SceneEstimator
from estimator.observations import ObservationReader
from physics.scene import load_scene


DEFAULT_PARTICLES = 64
"""Particle worlds K of ``run``, ``config``, ``track --feedback`` and ``demo`` when neither the
command line (``--particles``, ``--paper``) nor a configuration file says: every built-in scenario
runs in real time at K = 64 on two cores (README, *Speed*)."""


def _particles(args, file_data) -> int | None:
    """K asked for: ``--paper`` is 1, else ``--particles``; ``None`` when a configuration file
    decides (it names ``particles`` or ``base: paper``); else :data:`DEFAULT_PARTICLES`."""
    if getattr(args, "paper", False):
        if args.particles not in (None, 1) or args.noise:
            raise ValueError("--paper is one world without noise: drop --particles / --noise")
        return 1
    if args.particles is not None:
        return args.particles
    if isinstance(file_data, dict) and ("particles" in file_data or file_data.get("base") == "paper"):
        return None
    return DEFAULT_PARTICLES


def build_config(args) -> EstimatorConfig:
    """Estimator configuration from ``run`` arguments. Without ``--config``, the particle filter
    with :data:`DEFAULT_PARTICLES` worlds and its default noise; ``--paper`` (or ``--particles 1``)
    is the paper's reasoner unless ``--noise`` is given; more particles use the default noise unless
    ``--no-noise``. A configuration file (``--config``) changes the fields it names; options given
    on the command line win over the file."""
    paper = getattr(args, "paper", False)
    base = "particles" if args.noise else ("paper" if args.no_noise or paper else None)
    file_data = None
    if args.config:
        file_data, lines = read_config_file(args.config)
        cfg = config_from_dict(file_data, path=args.config, lines=lines, particles=_particles(args, file_data),
                               base=base)
    else:
        cfg = default_config(_particles(args, None), base)
    given = {name: getattr(args, name) for name in ("horizon", "t_perceived", "d_sim_perc", "d_perc_prev")
             if getattr(args, name) is not None}
    if given:
        cfg = dataclasses.replace(cfg, reasoner=dataclasses.replace(cfg.reasoner, **given))
    workers = args.workers
    if workers is None and not (isinstance(file_data, dict) and "workers" in file_data):
        workers = (os.cpu_count() or 1) if cfg.particles > 1 else 0
    if workers is not None:
        cfg = dataclasses.replace(cfg, workers=workers)
    args.workers = cfg.workers
    return cfg


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
    from .rosbag_io import BagFrameReader
    from .rosbag_topics import default_topics, load_topics

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
        from .rosbag_out import BagEstimateWriter
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


def _add_run_arguments(p: argparse.ArgumentParser) -> None:
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
    _add_estimator_arguments(p)
    p.add_argument("--rerun", metavar="PATH", help="also write a rerun recording (.rrd); open it with `rerun PATH`")
    p.add_argument("--skip-bad-frames", action="store_true",
                   help="drop malformed frames with a counted warning instead of stopping")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _add_estimator_arguments(p: argparse.ArgumentParser) -> None:
    d = ReasonerConfig()
    p.add_argument("--config", metavar="FILE",
                   help="estimator configuration file (YAML or JSON): the fields to change, e.g. "
                        "'noise: {position_std: 0.02}'; `scene-estimator config` prints them all")
    p.add_argument("--particles", type=int, default=None,
                   help=f"particle worlds K (default {DEFAULT_PARTICLES}, or the configuration file's; "
                        "1: the paper's reasoner)")
    p.add_argument("--paper", action="store_true",
                   help="the paper's reasoner: one world, no noise (same as --particles 1)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes holding the particle worlds (0: in this process; "
                        "default: one per core when there is more than one particle)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--noise", action="store_true", help="perturb even with one particle")
    p.add_argument("--no-noise", action="store_true", help="no perturbation even with many particles")
    p.add_argument("--horizon", type=float, default=None, help=f"reasoning period in s ({d.horizon})")
    p.add_argument("--t-perceived", type=float, default=None, help=f"perceived timeout in s ({d.t_perceived})")
    p.add_argument("--d-sim-perc", type=float, default=None, help=f"simulation tolerance in m ({d.d_sim_perc})")
    p.add_argument("--d-perc-prev", type=float, default=None, help=f"perception jump in m ({d.d_perc_prev})")


def print_summary(summary: dict, stream=None) -> None:
    """A readable timeline and the final poses."""
    stream = stream or sys.stdout
    tl = summary["timeline"]
    print(f"{summary['frames']} frames read, {summary['skipped']} skipped, {summary['estimates']} "
          f"reasoning steps in {summary['seconds']:.2f} s", file=stream)
    if summary.get("rejected"):
        print(f"{summary['rejected']} detection(s) outside the scene's workspace rejected as outliers", file=stream)
    if summary.get("reseeded") or summary.get("worker_restarts"):
        print(f"{summary.get('reseeded', 0)} particle(s) re-seeded from the others after an exploded simulation "
              f"or a dead worker; {summary.get('worker_restarts', 0)} worker restart(s)", file=stream)
    print("\nEvents:", file=stream)
    for e in tl["events"]:
        print(f"  t={e['t']:7.3f}  {e['action']:<8} {e['subject']:<14} p={e['p']:.2f}", file=stream)
    if not tl["events"]:
        print("  (none)", file=stream)
    print("\nFacts:", file=stream)
    for f in tl["facts"]:
        if f["predicate"] == "isPerceived":
            continue
        rel = f"{f['predicate']}({f['subject']}" + (f", {f['object']})" if f["object"] else ")")
        end = "..." if f["end"] is None else f"{f['end']:.3f}"
        print(f"  {rel:<36} {f['start']:7.3f} -> {end:<8} confidence {f['confidence']:.2f}", file=stream)
    b = summary["last_belief"]
    if b is not None:
        print(f"\nFinal poses (t={b.t:.3f} s):", file=stream)
        for oid, ob in b.objects.items():
            pos = ", ".join(f"{v:+.3f}" for v in ob.position)
            where = ", ".join(f"{h.relation} {h.support or ''}".strip() + f" {h.p:.2f}" for h in ob.hypotheses)
            seen = "perceived" if ob.perceived else "hidden   "
            if not ob.hypotheses and ob.p_held == 0 and not ob.perceived:
                seen = "static   "
            print(f"  {oid:<14} [{pos}]  {seen}  {where}", file=stream)


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
        from .recording import Recorder
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scene-estimator", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="estimate a recorded observation stream")
    _add_run_arguments(p_run)
    p_run.set_defaults(func=cmd_run)
    p_cfg = sub.add_parser("config", help="print the estimator configuration (all fields) that `run` would use")
    _add_estimator_arguments(p_cfg)
    p_cfg.add_argument("--json", action="store_true", help="JSON instead of YAML")
    p_cfg.set_defaults(func=cmd_config)
    from .demo_cli import add_demo_arguments, run_demo

    p_demo = sub.add_parser("demo", help="run the built-in example")
    add_demo_arguments(p_demo)
    p_demo.set_defaults(func=run_demo)
    from .bench import add_bench_arguments, run_bench
    from .evaluate_cli import add_evaluate_arguments, run_evaluate
    from .fit_priors import add_fit_arguments, run_fit
    from .search_cli import add_search_arguments, run_search
    from .simulate_cli import add_simulate_arguments, run_simulate
    from .track_cli import add_track_arguments, run_track

    for name, text, add, run in [
            ("simulate", "simulate a scenario with ground truth", add_simulate_arguments, run_simulate),
            ("evaluate", "statistical evaluation over scenarios, seeds and methods", add_evaluate_arguments,
             run_evaluate),
            ("bench", "update time against bare pybullet stepping", add_bench_arguments, run_bench),
            ("track", "Kalman pose tracker over a stream, kept alive by the estimator with --feedback",
             add_track_arguments, run_track),
            ("fit-priors", "fit the held-object priors on simulated scenarios (seeds 100-119)", add_fit_arguments,
             run_fit),
            ("search", "where to look first for a hidden object: ranked places and a look plan",
             add_search_arguments, run_search)]:
        p_sub = sub.add_parser(name, help=text)
        add(p_sub)
        p_sub.set_defaults(func=run)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    try:
        return args.func(args)
    except ValueError as exc:  # InputError (file, line, field) included
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: the estimates written so far are kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
