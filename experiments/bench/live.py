"""``scene-estimator bench --scenario NAME --live``: latency of the live loop on a scenario's stream.

For each scenario (simulated once, seed 0, :func:`experiments.bench.scenarios.scenario_stream`) and
configuration: the particle worlds are built, then a writer thread writes the observation stream's
JSON lines into an OS pipe at its real rate (frame ``t`` at wall time ``start + t``,
:func:`experiments.streams.paced`), and the pipe's read end is the live loop's source exactly as
``run --observations - --live`` reads it (:class:`~estimator.observations.ObservationReader` in a
:class:`~experiments.live.FrameQueue` reader thread, :class:`~experiments.live.LiveLoop`).

A row (times in ms unless named ``_s``):

* ``latency_ms_median / p95 / max``: per frame, from its arrival (read from the pipe) to the end of
  the reasoning step that first used it (frames after the last step are not counted); a frame
  waits for the step running when it came (if any), for the horizon to pass, and for its own step;
* ``newest_latency_ms_p95``: per step, the latency of its newest frame (the step's own delay);
* ``merged``: frames that would have started a step of their own and were folded into a later one;
* ``k_mean``, ``k_min``: the particle count over the steps (a live run sheds particles while its
  steps cannot keep up: :class:`~estimator.config.BudgetConfig`; ``bench --live --fixed-particles``
  keeps K);
* ``update_ms_median / p95``: the steps' durations (observing their frames included);
* ``realtime_factor``: stream duration over the time the loop was busy (above 1: it keeps up);
* ``p95_over_horizon``, ``p95_over_update``, ``p95_over_update_p95``: the p95 latency over the
  reasoning horizon, over the median step time and over the p95 step time (the targets: at most
  1.5 at K = 64; under 3 times the update time at K = 512);
* ``rss_mb_half`` and ``rss_mb_end``: resident memory (MB, this process and its workers) half-way
  through the stream and at its end (a flat memory: the two alike);
* ``load_1min``: the machine's one-minute load average at the end (other work on the cores).
"""
from __future__ import annotations

import json
import os
import sys
import threading
import time
from typing import Iterator

import numpy as np

from estimator.config import EstimatorConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame, ObservationReader
from experiments.bench.timing import _rss_mb
from experiments.live import FrameQueue, LiveLoop
from experiments.streams import paced
from physics.scene import Scene

LIVE_COLUMNS = [("scenario", "scenario", "{}"), ("particles", "K", "{}"), ("frames", "frames", "{}"),
                ("steps", "steps", "{}"), ("merged", "merged", "{}"), ("k_mean", "K mean", "{:.0f}"),
                ("k_min", "K min", "{}"), ("realtime_factor", "real-time factor", "{:.2f}"),
                ("update_ms_median", "step median (ms)", "{:.1f}"), ("update_ms_p95", "step p95 (ms)", "{:.1f}"),
                ("latency_ms_median", "latency median (ms)", "{:.1f}"),
                ("latency_ms_p95", "latency p95 (ms)", "{:.1f}"), ("latency_ms_max", "latency max (ms)", "{:.1f}"),
                ("newest_latency_ms_p95", "newest frame's p95 (ms)", "{:.1f}"),
                ("p95_over_horizon", "p95 / horizon", "{:.2f}"), ("p95_over_update", "p95 / step", "{:.2f}"),
                ("p95_over_update_p95", "p95 / step p95", "{:.2f}"),
                ("rss_mb_half", "RSS half-way (MB)", "{:.0f}"), ("rss_mb_end", "RSS end (MB)", "{:.0f}"),
                ("load_1min", "load", "{:.2f}")]


def _write_paced(fd: int, frames: list[Frame], speed: float) -> None:
    """Write ``frames`` as JSON lines into the pipe ``fd`` at stream time (times ``1 / speed``),
    one flushed line per frame, then close it."""
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        try:
            for f in paced(frames, speed):
                fh.write(json.dumps(f.to_json()) + "\n")
                fh.flush()
        except BrokenPipeError:  # the reader stopped
            pass


def live_row(name: str, scene: Scene, frames: list[Frame], cfg: EstimatorConfig, seed: int = 0,
             speed: float = 1.0) -> dict:
    """Feed ``frames`` through a pipe at ``speed`` times their real rate into a live loop over a new
    estimator of ``cfg``; the figures of the module docstring."""
    est = SceneEstimator(scene, cfg, np.random.default_rng(seed))
    with est:
        pids = [os.getpid()] + est.pool.worker_pids()
        r, w = os.pipe()
        queue = FrameQueue()
        queue.feed(ObservationReader("<pipe>", scene.object_ids, stream=os.fdopen(r, "r", encoding="utf-8")))
        writer = threading.Thread(target=_write_paced, args=(w, frames, speed), daemon=True)
        t_half = frames[0].t + 0.5 * (frames[-1].t - frames[0].t)
        loop = LiveLoop(est, queue)
        latencies, newest, seconds = [], [], []
        rss_half = None
        writer.start()
        for step in loop:
            latencies.extend(step.done - a for a in step.arrived)
            newest.append(step.latency)
            seconds.append(step.seconds)
            if rss_half is None and step.belief.t >= t_half:
                rss_half = _rss_mb(pids)
        rss_end = _rss_mb(pids)
        writer.join()
    if not seconds:
        raise ValueError(f"{name}: no reasoning step ran")
    stream_s = (frames[-1].t - frames[0].t) / speed
    lat = 1e3 * np.asarray(latencies)
    p95 = float(np.percentile(lat, 95))
    step_med, step_p95 = 1e3 * float(np.median(seconds)), 1e3 * float(np.percentile(seconds, 95))
    shown = "auto" if cfg.adaptive.enabled else cfg.particles
    k_min, _, k_total = est.k_range
    return {"scenario": name, "particles": shown, "workers": cfg.workers, "frames": loop.frames,
            "steps": loop.steps, "merged": loop.merged, "k_mean": k_total / max(est.n_updates, 1), "k_min": k_min,
            "stream_s": stream_s, "busy_s": loop.busy_seconds,
            "realtime_factor": stream_s / loop.busy_seconds if loop.busy_seconds > 0 else float("inf"),
            "update_ms_median": step_med, "update_ms_p95": step_p95,
            "latency_ms_median": float(np.median(lat)), "latency_ms_p95": p95, "latency_ms_max": float(lat.max()),
            "newest_latency_ms_p95": 1e3 * float(np.percentile(newest, 95)),
            "p95_over_horizon": p95 / (1e3 * cfg.reasoner.horizon), "p95_over_update": p95 / step_med,
            "p95_over_update_p95": p95 / step_p95,
            "rss_mb_half": rss_half if rss_half is not None else rss_end, "rss_mb_end": rss_end,
            "load_1min": os.getloadavg()[0]}


def live_rows(names: list[str], configs: list[tuple[int | str, EstimatorConfig]], speed: float = 1.0,
              repeat: int = 1) -> Iterator[dict]:
    """One :func:`live_row` per scenario and ``(K, configuration)``, as each is measured, ``repeat``
    rounds of them (:func:`~experiments.bench.scenarios.scenario_rounds`); progress on stderr."""
    from experiments.bench.scenarios import SEED, scenario_rounds

    def measure(name: str, scene: Scene, frames: list[Frame], k: int | str, cfg: EstimatorConfig) -> dict:
        print(f"bench: {name}, K={k}, live: {len(frames)} frames over "
              f"{(frames[-1].t - frames[0].t) / speed:.1f} s", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        row = live_row(name, scene, frames, cfg, SEED, speed)
        row["wall_s"] = time.perf_counter() - t0
        return row

    yield from scenario_rounds(names, configs, repeat, measure)
