"""``scene-estimator bench --scenario NAME``: the estimator's speed on a simulated scenario's stream.

The scenario is simulated once (seed 0, :func:`experiments.simulation.simulator.simulate`), its files written to
a temporary folder and read back as ``scene-estimator run`` reads them
(:class:`~estimator.observations.ObservationReader`); then, for each particle count, every frame of
the stream goes through a new estimator (:func:`experiments.bench.timing.time_stream`). Besides the update
and bare-stepping figures of the synthetic benchmark, a row has the stream's duration
(``stream_s``: the frames' time span plus one frame period), the time all ``update`` calls took
(``processing_s``, frames between reasoning steps included) and their quotient, the real-time factor
(above 1: faster than the stream comes in). The update statistics are over the reasoning steps that
simulated: all but the first, which only places the objects.
"""
from __future__ import annotations

import contextlib
import sys
import tempfile
from typing import Callable, Iterator

import numpy as np

from estimator.config import EstimatorConfig
from estimator.observations import Frame, ObservationReader
from experiments.bench.repeat import rounds
from experiments.bench.timing import RESOURCE_COLUMNS, TIMING_COLUMNS, time_stream, timing_row
from physics.scene import Scene, load_scene

SEED = 0

SCENARIO_COLUMNS = ([("scenario", "scenario", "{}"), ("particles", "K", "{}"), ("updates", "updates", "{}"),
                     ("stream_s", "stream (s)", "{:.2f}"), ("processing_s", "processing (s)", "{:.2f}"),
                     ("realtime_factor", "real-time factor", "{:.2f}")]
                    + TIMING_COLUMNS + RESOURCE_COLUMNS)


@contextlib.contextmanager
def scenario_stream(name: str, seed: int = SEED) -> Iterator[tuple[Scene, list[Frame]]]:
    """The estimator's scene and the observation frames of ``name``'s simulation (``seed``), read back
    from the files ``scene-estimator simulate`` writes (in a temporary folder, kept while in use)."""
    from experiments.simulation.simulator import simulate, write_outputs

    result = simulate(name, seed)
    with tempfile.TemporaryDirectory(prefix="bench_") as tmp:
        paths = write_outputs(result, tmp)
        scene = load_scene(str(paths["scene.yaml"]))
        frames = list(ObservationReader(str(paths["observations.jsonl"]), scene.object_ids))
        yield scene, frames


def bag_table(names: list[str], configs: list[tuple[int, EstimatorConfig]]) -> Iterator[dict]:
    """``bench --bag`` rows: for each scenario and configuration, a run of the stream read from JSON
    Lines against one read from a ROS 2 bag of the same detections (:func:`experiments.bench.bag.bag_rows`)."""
    from experiments.bench.bag import bag_rows

    for name in names:
        with scenario_stream(name) as (scene, frames):
            yield from bag_rows(name, scene, frames, configs)


def scenario_rounds(names: list[str], configs: list[tuple[int | str, EstimatorConfig]], repeat: int,
                    measure: Callable[[str, Scene, list[Frame], int | str, EstimatorConfig], dict]) -> Iterator[dict]:
    """``measure(name, scene, frames, k, cfg)`` for every scenario and ``(K, configuration)``,
    ``repeat`` rounds of them (:func:`~experiments.bench.repeat.rounds`): each scenario simulated once,
    when first measured, its stream kept until the last round; progress on stderr."""
    with contextlib.ExitStack() as stack:
        streams: dict[str, tuple[Scene, list[Frame]]] = {}

        def one(item: tuple[str, int | str, EstimatorConfig]) -> dict:
            name, k, cfg = item
            if name not in streams:
                print(f"bench: simulating {name} (seed {SEED})", file=sys.stderr, flush=True)
                streams[name] = stack.enter_context(scenario_stream(name))
            return measure(name, *streams[name], k, cfg)

        yield from rounds([(name, k, cfg) for name in names for k, cfg in configs], one, repeat)


def scenario_rows(names: list[str], configs: list[tuple[int | str, EstimatorConfig]],
                  max_updates: int | None = None, resting: bool = False, repeat: int = 1) -> Iterator[dict]:
    """One row (:data:`SCENARIO_COLUMNS` and more) per scenario and ``(K, configuration)``, as each
    is measured, ``repeat`` rounds of them (:func:`scenario_rounds`); progress on stderr.
    ``max_updates``: stop each stream after that many timed updates; ``resting``: measure the
    resting objects' share of bare stepping too (:func:`~experiments.bench.timing.time_stream`)."""

    def measure(name: str, scene: Scene, frames: list[Frame], k: int | str, cfg: EstimatorConfig) -> dict:
        print(f"bench: {name}, K={k}: {len(frames)} frames", file=sys.stderr, flush=True)
        st = time_stream(scene, cfg, frames, np.random.default_rng(SEED), max_updates=max_updates,
                         resting=resting)
        shown = f"auto ({np.mean(st.particles):.0f}, max {max(st.particles)})" if k == "auto" and \
            st.particles else k
        return {"scenario": name, "particles": shown, "workers": cfg.workers,
                "frames": len(st.frame_times), "stream_s": st.stream_s,
                "processing_s": st.processing_s, "realtime_factor": st.stream_s / st.processing_s,
                **timing_row(st)}

    yield from scenario_rounds(names, configs, repeat, measure)
