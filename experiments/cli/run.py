"""``run`` (estimate a recorded stream, JSONL or ROS bag) and ``config`` (the configuration ``run``
would use)."""
from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import json
import os
import stat
import sys
import time

import numpy as np

from estimator.config import EstimatorConfig, config_to_dict
from estimator.filter import SceneEstimator
from estimator.observations import ObservationReader
from experiments.cli.common import (
    add_estimator_arguments,
    add_fixed_particles_argument,
    build_config,
    live_config,
    print_summary,
)
from experiments.live import MIN_TIMELINE_WINDOW, TIMELINE_WINDOW, FrameQueue, LiveLoop
from experiments.streams import (
    STDIO,
    LineOutput,
    PathOption,
    StagedFile,
    StopSignals,
    check_paths,
    open_observations,
    paced,
    silence_stdout,
    write_text,
)
from physics.errors import InputError
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


@dataclasses.dataclass(frozen=True)
class StreamOptions:
    """How ``run`` takes its stream.

    ``live``: take the frames as they arrive and never fall behind the newest by more than one
    reasoning step (:mod:`experiments.live`: frames that arrive during a step are merged into the
    next; each estimate line gets ``merged`` and ``latency``). ``realtime``: replay at stream time
    times this speed (frame ``t`` is made available at wall time ``start + t / realtime``; None: as
    fast as it is read). ``timeline_window``: keep the timeline's facts and events of the last this
    many seconds of stream time (None: all), so that an endless stream's memory stays bounded."""

    live: bool = False
    realtime: float | None = None
    timeline_window: float | None = None

    def __post_init__(self):
        if self.realtime is not None and not self.realtime > 0:
            raise ValueError(f"--realtime speed must be > 0, got {self.realtime}")
        if self.timeline_window is not None and not self.timeline_window >= MIN_TIMELINE_WINDOW:
            raise ValueError(f"--timeline-window must be >= {MIN_TIMELINE_WINDOW} s, got {self.timeline_window}")


STREAM_TIMELINE_WINDOW = TIMELINE_WINDOW
"""s: ``run``'s timeline window when the observations are not a regular file (standard input, a
FIFO, a socket) and ``--timeline-window`` is not given: an hour of facts and events."""
TIMES_KEPT = 1000
"""Reasoning steps whose times the summary's medians are over (the last ones): a bounded memory."""


def _frame_reader(scene, observations_path: str | None, bag: BagInput | None, skip_bad_frames: bool, warn):
    """The frames of a JSONL stream (a file, a FIFO, ``-`` for standard input, ``tcp://HOST:PORT``)
    or of a bag: an iterable with ``frames_read`` and ``skipped``."""
    if (observations_path is None) == (bag is None):
        raise ValueError("give exactly one of an observation stream (--observations) and a bag (--bag)")
    if bag is None:
        name, stream = open_observations(observations_path)
        return ObservationReader(name, scene.object_ids, skip_bad_frames=skip_bad_frames, warn=warn, stream=stream)
    from experiments.ros.reader import BagFrameReader
    from experiments.ros.topics import default_topics, load_topics

    topics = (load_topics(bag.topics, scene.object_ids, bag.world_frame) if bag.topics
              else default_topics(scene.object_ids, bag.world_frame or "world"))
    return BagFrameReader(bag.path, topics, skip_bad_frames=skip_bad_frames, warn=warn)


def _is_regular_file(path: str | None) -> bool:
    try:
        return path not in (None, STDIO) and stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def run_stream(scene_path: str, observations_path: str | None, config: EstimatorConfig, seed: int,
               out_path: str | None, timeline_path: str | None, skip_bad_frames: bool = False,
               quiet: bool = False, on_belief=None, on_frame=None, bag: BagInput | None = None,
               stream: StreamOptions = StreamOptions(), on_start=None, signals: StopSignals | None = None) -> dict:
    """Estimate a whole observation stream (a JSONL file, a FIFO, ``-`` for standard input or
    ``tcp://HOST:PORT``, or a ROS bag given as ``bag`` with ``observations_path=None``), writing one
    estimate line per reasoning step as it goes (flushed, so an interrupted run keeps what it
    wrote; ``-``: standard output), the estimates also into ``bag.out`` when given, and the timeline
    at the end (also on interruption; ``-``: standard output).

    Outputs that exist are replaced only once the run has started cleanly: the scene loaded, the
    estimator built, the first frame read (``on_start()`` is called then, before that frame is
    processed; a stream that ends without a frame also counts as a clean start). A run that fails or
    is interrupted before leaves them as they were and writes no timeline. A reader of the estimates
    that went away (``| head``) ends the run as the end of the stream would (``output_closed`` in
    the summary). ``stream``: :class:`StreamOptions` (live, real-time replay, timeline window).
    ``signals``: a :class:`~experiments.streams.StopSignals` whose interruptions are deferred while a
    line or the timeline is written and while the run closes. ``on_frame(frame)`` and
    ``on_belief(belief)`` see every frame and every belief. Returns a summary dict."""
    scene = load_scene(scene_path)
    warnings: list[str] = []
    deferred = signals.deferred if signals is not None else contextlib.nullcontext

    def warn(msg: str) -> None:
        if len(warnings) < 100:
            warnings.append(msg)
        if not quiet:
            print(f"warning: {msg}", file=sys.stderr)

    window = stream.timeline_window
    if window is None and bag is None and not _is_regular_file(observations_path):
        window = STREAM_TIMELINE_WINDOW
    if stream.live and stream.realtime is None and _is_regular_file(observations_path):
        warn("--live on a file without --realtime: every frame is there at once, so the estimator skips "
             "ahead to the newest ones (merging the others); add --realtime to replay it at stream time")
    out = LineOutput(out_path) if out_path else None
    est = bag_out = None
    started = False
    n_est = 0
    times: collections.deque[float] = collections.deque(maxlen=TIMES_KEPT)
    latencies: collections.deque[float] = collections.deque(maxlen=TIMES_KEPT)
    loop = None
    output_closed = False
    t_start = time.perf_counter()

    def start() -> None:
        nonlocal started
        if started:
            return
        started = True
        if out is not None:
            out.start()
        if on_start is not None:
            on_start()

    def emit(belief, extra: dict | None) -> None:
        nonlocal n_est
        n_est += 1
        line = belief.to_json()
        if extra:
            line.update(extra)
        if window is not None and loop is None:  # the live loop does it itself
            est.timeline.forget_before(belief.t - window)
        with deferred():
            if out is not None:
                out.write(json.dumps(line))
            if bag_out is not None:
                bag_out.write(line)
            if on_belief is not None:
                on_belief(belief)

    try:
        reader = _frame_reader(scene, observations_path, bag, skip_bad_frames, warn)
        if bag is not None and bag.out:
            from experiments.ros.writer import BagEstimateWriter
            bag_out = BagEstimateWriter(bag.out, reader.topics.world_frame, reader.t0_ns)
        frames = paced(reader, stream.realtime) if stream.realtime else reader
        if stream.live:  # frames arrive (and are stamped) while the particle worlds are built
            queue = FrameQueue()
            queue.feed(frames)
        est = SceneEstimator(scene, config, np.random.default_rng(seed))
        try:
            if stream.live:
                def seen(frame):
                    start()
                    if on_frame is not None:
                        on_frame(frame)

                loop = LiveLoop(est, queue, on_frame=seen, timeline_window=window)
                for step in loop:
                    times.append(step.seconds)
                    latencies.append(step.latency)
                    emit(step.belief, {"merged": step.merged, "latency": round(step.latency, 4)})
            else:
                for frame in frames:
                    start()
                    if on_frame is not None:
                        on_frame(frame)
                    t0 = time.perf_counter()
                    belief = est.update(frame)
                    if belief is None:
                        continue
                    times.append(time.perf_counter() - t0)
                    emit(belief, None)
            start()  # a stream without a frame ended cleanly too
        except BrokenPipeError:
            output_closed = True  # the reader of the estimates went away: the run ends here
    finally:
        with deferred():
            if est is not None:
                est.close()
            if out is not None:
                out.close()
            if bag_out is not None:
                bag_out.close()
            if timeline_path and started:
                write_text(timeline_path, json.dumps(est.timeline.to_json(), indent=1) + "\n", "--timeline")
    summary = {"frames": reader.frames_read, "skipped": reader.skipped, "estimates": n_est,
               "seconds": time.perf_counter() - t_start,
               "update_ms_median": 1e3 * float(np.median(times)) if times else None,
               "timeline": est.timeline.to_json(), "last_belief": est.last_belief,
               "recoveries": est.recoveries, "rejected": est.rejected_detections,
               "reseeded": est.reseeded, "worker_restarts": est.pool.restarts,
               "late": getattr(reader, "late", 0), "output_closed": output_closed}
    if est.config.varying_count and est.n_updates:
        lo, hi, total = est.k_range
        summary["particles"] = {"min": lo, "mean": total / est.n_updates, "max": hi,
                                "adaptive": est.config.adaptive.enabled, "budget": est.config.budget.enabled}
    if loop is not None:
        summary["live"] = {"steps": loop.steps, "merged": loop.merged, "max_latency_s": loop.max_latency,
                           "latency_s_median": float(np.median(latencies)) if latencies else None}
    return summary


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``run``."""
    p.add_argument("--scene", required=True, help="scene file (YAML or JSON)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--observations", metavar="PATH",
                     help="observation stream (JSON Lines): a file, a FIFO, - for standard input, or "
                          "tcp://HOST:PORT to connect to a tracker that serves it")
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
    p.add_argument("--out", metavar="PATH", help="estimate stream to write (JSON Lines; - for standard output)")
    p.add_argument("--timeline", metavar="PATH", help="timeline to write at the end (JSON; - for standard output)")
    add_estimator_arguments(p)
    p.add_argument("--rerun", metavar="PATH", help="also write a rerun recording (.rrd); open it with `rerun PATH`")
    p.add_argument("--rerun-serve", metavar="WEB_PORT", nargs="?", type=int, const=9090, default=None,
                   help="live view: serve the recording to rerun viewers as it is made (gRPC on --rerun-grpc-port) "
                        "and rerun's web viewer on WEB_PORT (default 9090); the address to open is printed")
    p.add_argument("--rerun-grpc-port", metavar="PORT", type=int, default=9876,
                   help="with --rerun-serve: the gRPC port viewers connect to (default 9876)")
    p.add_argument("--rerun-connect", metavar="ADDR",
                   help="live view: send the recording to a running rerun viewer (HOST:PORT, PORT, or "
                        "rerun+http://HOST:PORT/proxy; start one with `rerun`)")
    p.add_argument("--live", action="store_true",
                   help="take frames as they arrive and never fall behind the newest by more than one reasoning "
                        "step: frames that arrive during a step are merged into the next (counted; estimate lines "
                        "get 'merged', 'latency' and 'particles'), and particles are shed while the steps cannot "
                        "keep up (see --fixed-particles)")
    add_fixed_particles_argument(p)
    p.add_argument("--realtime", metavar="SPEED", nargs="?", type=float, const=1.0, default=None,
                   help="replay the stream at stream time (frame t made available at start + t / SPEED; "
                        "default speed 1)")
    p.add_argument("--timeline-window", metavar="SECONDS", type=float, default=None,
                   help="keep the timeline's facts and events of the last SECONDS of stream time only (default: "
                        f"all for a file, {STREAM_TIMELINE_WINDOW:.0f} s for standard input, a FIFO or a socket)")
    p.add_argument("--skip-bad-frames", action="store_true",
                   help="drop malformed frames with a counted warning instead of stopping")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def _check_run_paths(args) -> None:
    """Refuse outputs that are inputs or each other (links too), before any file is opened."""
    inputs = [PathOption("--scene", args.scene), PathOption("--observations", args.observations),
              PathOption("--bag", args.bag), PathOption("--topics", args.topics),
              PathOption("--config", args.config)]
    outputs = [PathOption("--out", args.out), PathOption("--timeline", args.timeline),
               PathOption("--rerun", args.rerun), PathOption("--bag-out", args.bag_out)]
    for o in inputs[2:] + outputs[2:]:
        if o.value == STDIO:
            raise InputError("- (standard input / output) is not supported here", field=o.option)
    for o in inputs[:1]:
        if o.value == STDIO:
            raise InputError("the scene is read from a file (its URDF paths are relative to it)", field=o.option)
    check_paths(inputs, outputs)


def _live_view(args):
    """The :class:`~experiments.recording_options.LiveView` that ``--rerun-serve`` / ``--rerun-connect`` ask for."""
    if args.rerun_serve is None and args.rerun_connect is None:
        return None
    from experiments.recording_options import LiveView, grpc_url
    if args.rerun_connect is not None:
        grpc_url(args.rerun_connect)  # a malformed address is an error before the run
    return LiveView(serve=args.rerun_serve is not None, grpc_port=args.rerun_grpc_port,
                    web_port=args.rerun_serve, connect=args.rerun_connect)


def cmd_run(args) -> int:
    bag = None
    if args.bag:
        bag = BagInput(args.bag, args.topics, args.world_frame, args.bag_out)
    else:
        for name in ("topics", "world_frame", "bag_out"):
            if getattr(args, name):
                raise ValueError(f"--{name.replace('_', '-')} needs --bag")
    _check_run_paths(args)
    options = StreamOptions(live=args.live, realtime=args.realtime, timeline_window=args.timeline_window)
    config = live_config(build_config(args), args.live, args.fixed_particles)
    to_stdout = STDIO in (args.out, args.timeline)
    report = sys.stderr if to_stdout else sys.stdout  # standard output carries the data then
    with StopSignals() as signals:
        recorder = staged = None
        live = _live_view(args)
        try:
            if args.rerun or live is not None:
                from experiments.recording import Recorder
                staged = StagedFile(args.rerun, "--rerun") if args.rerun else None
                recorder = Recorder(staged.write_path if staged else None, load_scene(args.scene), live=live)
                if recorder.viewer_url and not args.quiet:
                    print(f"live view: open {recorder.viewer_url} in a browser "
                          f"(native viewer: rerun {live.grpc_uri()})", file=sys.stderr, flush=True)
            summary = run_stream(args.scene, args.observations, config, args.seed, args.out,
                                 args.timeline, args.skip_bad_frames, args.quiet,
                                 on_belief=recorder.log_belief if recorder else None,
                                 on_frame=recorder.log_frame if recorder else None, bag=bag, stream=options,
                                 on_start=staged.commit if staged else None, signals=signals)
            if recorder is not None:
                recorder.log_timeline(summary["timeline"])
        finally:
            with signals.deferred():
                if recorder is not None:
                    recorder.close()  # also on Ctrl-C: what was logged is kept
                if staged is not None:
                    staged.discard()  # never started: an existing recording is left as it was
    if summary["output_closed"] and args.out == STDIO:
        silence_stdout()
    if not args.quiet:
        try:
            print_summary(summary, report)
            if args.skip_bad_frames:
                print(f"\n{summary['skipped']} bad frame(s) skipped", file=sys.stderr)
            if summary["late"]:
                print(f"{summary['late']} bag message(s) too late to sort into place, dropped", file=sys.stderr)
            if "live" in summary:
                lv = summary["live"]
                med = lv["latency_s_median"]
                print(f"live: {lv['steps']} reasoning steps, {lv['merged']} frame(s) merged into later steps, "
                      f"latency median {1e3 * med if med is not None else float('nan'):.0f} ms, "
                      f"max {1e3 * lv['max_latency_s']:.0f} ms", file=sys.stderr)
            if summary["output_closed"]:
                print(f"the estimates' reader went away: stopped after {summary['estimates']} estimate(s)",
                      file=sys.stderr)
        except BrokenPipeError:
            silence_stdout()
    return 0


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``config``: the estimator's, as ``run`` takes them, and ``--json``."""
    add_estimator_arguments(p)
    p.add_argument("--json", action="store_true", help="JSON instead of YAML")


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
