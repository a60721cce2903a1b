"""The live loop: frames taken as they arrive, merged when a step is slow, never more than one step
behind the newest; frame by frame it is ``update`` exactly; its memory does not grow."""
import gc
import threading
import time
import tracemalloc

import numpy as np
import pytest

from estimator.config import EstimatorConfig, NoiseConfig, reasoning_due
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.live import FrameQueue, LiveLoop
from experiments.streams import paced
from helpers import TABLE_TOP, det, table_scene

BOX = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "mass": 0.2,
       "pose": {"position": [0.1, 0.0, TABLE_TOP + 0.03]}}
BALL = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
        "pose": {"position": [-0.2, 0.1, TABLE_TOP + 0.03]}}
RATE = 30.0  # frames per second


def frame(k: int) -> Frame:
    """Frame k of an endless stream at 30 Hz: the box lifted 25 cm for one second in every four (a
    Pick and a Place) with a tracked hand, the ball out of view one second in every three."""
    t = k / RATE
    phase = t % 4.0
    z = TABLE_TOP + 0.03 + (0.25 if 1.0 <= phase < 2.0 else 0.0)
    objects = {"box": det([0.1, 0.0, z])}
    if t % 3.0 < 2.0:
        objects["ball"] = det([-0.2, 0.1, TABLE_TOP + 0.03])
    hands = {"human/right": np.array([0.1, 0.0, z + 0.05])} if 0.9 <= phase < 2.1 else {}
    return Frame(round(t, 6), objects, hands)


def estimator(seed=0):
    return SceneEstimator(table_scene(BOX, BALL), EstimatorConfig(particles=4, workers=0, noise=NoiseConfig()),
                          np.random.default_rng(seed))


def due_frames(times, t_last, horizon):
    """How many of the frames at ``times`` start a reasoning step frame by frame, the last step at
    ``t_last`` (the definition of a merged frame, counted independently of the loop)."""
    n = 0
    for t in times:
        if reasoning_due(t_last, t, horizon):
            n, t_last = n + 1, t
    return n


def test_the_queue_hands_over_everything_queued_then_the_error_that_ended_the_stream():
    q = FrameQueue(clock=lambda: 5.0)
    assert q.take(timeout=0.01) == [] and not q.finished
    q.put(frame(0))
    q.put(frame(1), arrived=7.0)
    got = q.take()
    assert [a.frame.t for a in got] == [frame(0).t, frame(1).t] and [a.arrived for a in got] == [5.0, 7.0]
    q.put(frame(2))
    q.close(ValueError("line 4: bad"))
    q.put(frame(3))  # after the end: ignored
    assert [a.frame.t for a in q.take()] == [frame(2).t]  # the frames before the error first
    with pytest.raises(ValueError, match="line 4"):
        q.take()
    assert q.finished and q.take() == []


def test_a_reader_thread_feeds_the_queue_and_closes_it():
    q = FrameQueue()
    th = q.feed(frame(k) for k in range(10))
    th.join(30)
    got = q.take()
    assert [a.frame.t for a in got] == [frame(k).t for k in range(10)] and q.finished

    def broken():
        yield frame(0)
        raise ValueError("<stdin>:2: t: must be a finite number")

    q = FrameQueue()
    q.feed(broken()).join(30)
    assert len(q.take()) == 1
    with pytest.raises(ValueError, match="<stdin>:2"):
        q.take()


def test_frame_by_frame_the_live_loop_is_update_exactly():
    """A consumer that keeps up takes one frame at a time: the same beliefs, bit for bit."""
    frames = [frame(k) for k in range(90)]
    with estimator() as ref:
        expected = [b.to_json() for b in ref.run(frames)]
        ref_poses, ref_logw = ref.state.poses.copy(), ref.state.log_weights.copy()
    q = FrameQueue()
    got = []
    with estimator() as est:
        loop = LiveLoop(est, q)
        for f in frames:
            q.put(f)
            step = loop.poll()
            if step is not None:
                assert step.merged == 0 and step.frames >= 1
                got.append(step.belief.to_json())
        q.close()
        assert loop.poll() is None and est._pending is None  # the last step's resampling, run by the poll
        assert np.array_equal(est.state.poses, ref_poses) and np.array_equal(est.state.log_weights, ref_logw)
    assert got == expected and len(got) == 30
    assert loop.merged == 0 and loop.steps == 30 and loop.frames == 90


def test_frames_queued_during_a_step_are_merged_into_the_next():
    """Arrivals decided by the test: 2 frames, then 10 at once, then 1."""
    q = FrameQueue()
    with estimator() as est:
        loop = LiveLoop(est, q)
        horizon = est.config.reasoner.horizon
        for k in range(2):
            q.put(frame(k))
        first = loop.poll()
        assert first.frames == 2 and first.merged == 0 and first.belief.t == frame(1).t
        for k in range(2, 12):
            q.put(frame(k))
        step = loop.poll()
        times = [frame(k).t for k in range(2, 12)]
        assert step.belief.t == times[-1] and step.frames == 10  # at the newest, all observed
        assert step.merged == due_frames(times, first.belief.t, horizon) - 1 == 2
        assert est.t_tick == times[-1] and est.n_updates == 2
        q.put(frame(12))  # 1/30 s after the last step: no step due
        assert loop.poll() is None and loop.frames == 13 and loop.merged == 2
        q.close()
        assert list(loop) == [] and loop.finished


def test_a_slow_estimator_never_falls_more_than_one_step_behind(monkeypatch):
    """Frames at 30 Hz from a paced reader thread; every reasoning step sleeps 0.25 s (3 horizons).
    At each step, the newest frame fed so far is at most one horizon of stream time ahead of the
    newest one observed (a frame may come in while the batch is observed); frames are merged, and
    their count is what the frames observed between steps say."""
    n = 60
    fed = []  # stream time of the frames fed so far
    fed_lock = threading.Lock()

    def source():
        for f in paced((frame(k) for k in range(n)), speed=1.0):
            with fed_lock:
                fed.append(f.t)
            yield f

    lags = []
    with estimator() as est:
        horizon = est.config.reasoner.horizon
        step = est.step

        def slow_step(defer=False):
            with fed_lock:
                lags.append(fed[-1] - est.t_frame)
            time.sleep(0.25)
            return step(defer)

        monkeypatch.setattr(est, "step", slow_step)
        q = FrameQueue()
        q.feed(source())
        loop = LiveLoop(est, q)
        steps = list(loop)
    assert loop.frames == n
    assert max(lags) <= horizon + 1e-9, lags
    assert loop.merged == sum(s.merged for s in steps) >= 1
    seen = 0
    t_last = None
    for s in steps:
        times = [frame(k).t for k in range(seen, seen + s.frames)]
        assert s.belief.t == times[-1]
        assert s.merged == due_frames(times, t_last, horizon) - 1
        seen += s.frames
        t_last = s.belief.t
    # the frames after the last step (if any) did not make a step due
    assert due_frames([frame(k).t for k in range(seen, n)], t_last, horizon) == 0
    # frame by frame, the same stream starts a step every 3 frames: 20 steps of 0.25 s for 2 s of it
    assert due_frames([frame(k).t for k in range(n)], None, horizon) == 20 and len(steps) < 20


def test_memory_does_not_grow_over_an_endless_stream():
    """Python allocations made by the project's code (tracemalloc, filtered to its folders) between
    frames 2100 and 3600 of a lazily generated stream (a Pick and a Place every 4 s, an object out of
    view every 3 s), once the loop has run 600 frames: a frame or an update time kept per step would
    add 10 kB or more (500 steps), the timeline without its window 19 kB; what is measured with it
    is the churn of arrays in flight, a few kB either way."""
    q = FrameQueue()
    marks = {}
    n0, n = 600, 1500

    def frames():
        k = 0
        while True:
            if k == n0:
                tracemalloc.start()
            if k in (n0 + n, n0 + 2 * n):
                gc.collect()
                marks[k] = tracemalloc.take_snapshot()
            if k == n0 + 2 * n:
                return
            yield frame(k)
            k += 1

    with estimator() as est:
        loop = LiveLoop(est, q, timeline_window=10.0)
        try:
            for f in frames():  # in lockstep (put, then poll): every step runs, nothing is merged
                q.put(f)
                loop.poll()
        finally:
            tracemalloc.stop()
    assert loop.steps >= (n0 + 2 * n) // 3 - 1 and loop.merged == 0
    assert len(est.timeline.events) <= 6 and est.timeline.to_json()["kept_since"] > 100  # 10 s kept of 120 s
    project = [tracemalloc.Filter(True, f"*/{d}/*") for d in ("estimator", "experiments", "actions", "physics")]
    a, b = (marks[k].filter_traces(project) for k in (n0 + n, n0 + 2 * n))
    growth = sum(s.size_diff for s in b.compare_to(a, "filename"))
    total = sum(s.size_diff for s in marks[n0 + 2 * n].compare_to(marks[n0 + n], "filename"))
    print(f"tracemalloc growth over {n} frames: {growth} B in the project's code, {total} B in all")
    assert growth < 4096, b.compare_to(a, "lineno")[:5]
