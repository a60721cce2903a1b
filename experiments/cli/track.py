"""``scene-estimator track``: a Kalman pose tracker over an observation stream, optionally kept alive
through occlusion by the physics estimator's belief.

::

    scene-estimator track --scene s.yaml --observations o.jsonl --out tracked.jsonl
    scene-estimator track --scene s.yaml --observations o.jsonl --out tracked.jsonl --feedback --particles 64

Writes one line per input frame, in the observation format (``t``, ``objects`` with ``position``,
``orientation`` when known and ``position_std``, ``hands`` passed through), so that ``scene-estimator
run`` accepts it. Without ``--feedback`` the stream is what the tracker alone believes (its
constant-velocity prediction for ``--coast`` seconds after an object is lost, then nothing). With
``--feedback`` the estimator runs beside the tracker on the raw detections, and at each of its
reasoning steps its belief gives pseudo-measurements for the scene's dynamic objects the tracker does
not see, so a hidden object stays in the stream with a ``position_std`` that grows with the
estimator's uncertainty.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from estimator.applications.tracker import PhysicsAwareTracker, TrackerConfig
from estimator.observations import ObservationReader
from physics.scene import load_scene


def add_track_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``track`` to ``parser`` (the estimator's options are those of ``run``)."""
    from experiments.cli.common import add_estimator_arguments

    d = TrackerConfig()
    parser.add_argument("--scene", required=True, help="scene file (YAML or JSON)")
    parser.add_argument("--observations", required=True, help="observation stream (JSON Lines)")
    parser.add_argument("--out", required=True, help="tracked stream to write (JSON Lines, observation format)")
    parser.add_argument("--feedback", action="store_true",
                        help="run the estimator beside the tracker; its belief keeps hidden objects tracked")
    parser.add_argument("--accel-std", type=float, default=d.accel_std,
                        help=f"white acceleration of the constant-velocity model, m/s^2 ({d.accel_std})")
    parser.add_argument("--measurement-std", type=float, default=d.measurement_std,
                        help=f"position noise of a detection without position_std, m ({d.measurement_std})")
    parser.add_argument("--coast", type=float, default=d.coast_time,
                        help=f"seconds an unsupported track is predicted before it is dropped ({d.coast_time})")
    parser.add_argument("--fusion", choices=("kalman", "replace"), default=d.pseudo_fusion,
                        help="how a pseudo-measurement from the estimator enters a hidden object's track: a "
                             f"Kalman update, or a restart at the belief ({d.pseudo_fusion})")
    add_estimator_arguments(parser)
    parser.add_argument("--skip-bad-frames", action="store_true",
                        help="drop malformed frames with a counted warning instead of stopping")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def track_stream(scene_path: str, observations_path: str, out_path: str, tracker_config: TrackerConfig,
                 estimator_config=None, seed: int = 0, skip_bad_frames: bool = False,
                 quiet: bool = False) -> dict:
    """Track a whole stream, writing (and flushing) one tracked frame per input frame. With
    ``estimator_config`` the estimator runs beside the tracker on the raw frames and feeds it back
    (``tracker_config.use_feedback`` must then be on to have an effect). Returns a summary dict."""
    scene = load_scene(scene_path)
    dynamic = tuple(o.id for o in scene.objects if not o.static)

    def warn(msg: str) -> None:
        if not quiet:
            print(f"warning: {msg}", file=sys.stderr)

    reader = ObservationReader(observations_path, scene.object_ids, skip_bad_frames=skip_bad_frames, warn=warn)
    tracker = PhysicsAwareTracker(tracker_config, dynamic)
    est = None
    if estimator_config is not None:
        from estimator.filter import SceneEstimator
        est = SceneEstimator(scene, estimator_config, np.random.default_rng(seed))
    frames = feedbacks = kept_hidden = 0
    t_start = time.perf_counter()
    try:
        with open(out_path, "w", encoding="utf-8") as out:
            for frame in reader:
                tracker.update(frame)
                if est is not None:
                    belief = est.update(frame)
                    if belief is not None:
                        feedbacks += len(tracker.feedback(belief))
                tracked = tracker.to_frame(frame.t, frame.hands)
                kept_hidden += len(set(tracked.objects) - set(frame.objects))
                out.write(json.dumps(_rounded(tracked.to_json())) + "\n")
                out.flush()
                frames += 1
    finally:
        if est is not None:
            est.close()
    return {"frames": frames, "skipped": reader.skipped, "rejections": tracker.rejections,
            "reinitialisations": tracker.reinitialisations, "pseudo_measurements": feedbacks,
            "pseudo_resets": tracker.pseudo_resets, "hidden_object_frames": kept_hidden,
            "dropped": len(tracker.dropped), "seconds": time.perf_counter() - t_start}


def _rounded(value, digits: int = 7):
    """``value`` (a JSON tree) with every float rounded to ``digits`` significant digits (a positive
    ``position_std`` stays positive)."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}")
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v, digits) for v in value]
    return value


def run_track(args: argparse.Namespace) -> int:
    """Run the ``track`` subcommand; bad input raises :class:`ValueError` (reported by ``main``)."""
    from experiments.cli.common import build_config

    tracker_config = TrackerConfig(accel_std=args.accel_std, measurement_std=args.measurement_std,
                                   coast_time=args.coast, use_feedback=args.feedback,
                                   pseudo_fusion=args.fusion)
    est_config = build_config(args) if args.feedback else None
    s = track_stream(args.scene, args.observations, args.out, tracker_config, est_config, args.seed,
                     args.skip_bad_frames, args.quiet)
    if not args.quiet:
        print(f"{s['frames']} frames tracked in {s['seconds']:.2f} s ({s['skipped']} skipped): "
              f"{s['rejections']} detection(s) rejected by the gate, {s['reinitialisations']} re-initialisation(s), "
              f"{s['dropped']} track(s) dropped; {s['pseudo_measurements']} pseudo-measurement(s) from the "
              f"estimator ({s['pseudo_resets']} restart(s)); {s['hidden_object_frames']} object-frame(s) "
              f"not detected but tracked")
        print(f"wrote {args.out}")
    return 0
