"""Live estimation with bounded latency: frames are taken as they arrive, and the estimator never
falls behind the newest frame by more than one reasoning step.

A :class:`FrameQueue` receives frames as they arrive, from a reader thread over any iterable
(:meth:`FrameQueue.feed`: a JSONL stream on standard input, a socket, a paced file) or from a
callback (:meth:`FrameQueue.put`: a ROS subscriber), stamping each with its arrival time. A
:class:`LiveLoop` takes *everything* queued at once, records all of it in the perception memory
(:meth:`SceneEstimator.observe <estimator.filter.SceneEstimator.observe>`: the velocity fit keeps
every detection) and runs one reasoning step
(:meth:`SceneEstimator.step <estimator.filter.SceneEstimator.step>`) at the newest frame when a
step is due, i.e. when the horizon has passed since the last one. That step simulates the whole
elapsed time (at most ``max_gap``). Its resampling is deferred (``step(defer=True)``): the belief
is handed out first, and the loop resamples when it is next polled, before it waits for frames
(:meth:`SceneEstimator.finish <estimator.filter.SceneEstimator.finish>`; the same beliefs either way).

When the estimator keeps up, every take holds one frame and the loop does exactly what
``update(frame)`` does frame by frame (the same beliefs, bit for bit). When a step takes longer than
the frames' period, the frames that arrived meanwhile are *merged* into the next step: a frame that
would have started a reasoning step of its own (:func:`~estimator.config.reasoning_due`, counted from
the last step run) but was folded into a later one is a merged frame. ``LiveStep.merged`` counts
them per step; :attr:`LiveLoop.merged` over the run.

Latency (seconds, on the queue's clock, ``time.monotonic`` by default): from a frame's arrival to
the end of the reasoning step that first used it. The newest frame of a step waits at most for the
step before it to end; an older one also for the horizon to pass.

    queue = FrameQueue()
    queue.feed(ObservationReader("<stdin>", scene.object_ids, stream=sys.stdin))
    for step in LiveLoop(estimator, queue):
        publish(step.belief, merged=step.merged, latency=step.latency)
"""
from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable

from estimator.belief import Belief
from estimator.config import reasoning_due
from estimator.observations import Frame

TIMELINE_WINDOW = 3600.0
"""s: how much of the timeline a live run keeps by default (an hour of facts and events)."""
MIN_TIMELINE_WINDOW = 10.0
"""s: a shorter timeline window could forget an event that a later update still refines."""


@dataclass(frozen=True)
class Arrival:
    """A frame and when it arrived (s, on the queue's clock)."""

    frame: Frame
    arrived: float


class FrameQueue:
    """Frames in arrival order, for one consumer that takes all of them at once (thread-safe).

    Producers call :meth:`put` (a callback source) or :meth:`feed` (a reader thread over an
    iterable), then :meth:`close` at the end of the stream (``feed`` does), optionally with the
    exception that ended it: :meth:`take` raises it once the frames before it are taken.
    ``clock``: the arrival clock (s).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self._items: collections.deque[Arrival] = collections.deque()
        self._cond = threading.Condition()
        self._closed = False
        self._error: BaseException | None = None
        self.thread: threading.Thread | None = None

    def put(self, frame: Frame, arrived: float | None = None) -> None:
        """A frame arrived (now, or at ``arrived`` on the clock). Ignored after :meth:`close`."""
        arrival = Arrival(frame, self.clock() if arrived is None else arrived)
        with self._cond:
            if self._closed:
                return
            self._items.append(arrival)
            self._cond.notify()

    def close(self, error: BaseException | None = None) -> None:
        """The stream ended (``error``: the exception that ended it, raised by :meth:`take`)."""
        with self._cond:
            if not self._closed:
                self._closed, self._error = True, error
            self._cond.notify_all()

    @property
    def finished(self) -> bool:
        """Closed and every frame taken (the error, if any, raised)."""
        with self._cond:
            return self._closed and not self._items and self._error is None

    def take(self, timeout: float | None = None) -> list[Arrival]:
        """Every frame queued, oldest first, waiting up to ``timeout`` s (None: as long as it takes)
        for one; an empty list when the wait ran out or the stream ended (:attr:`finished`). Raises
        the exception the stream ended with once the frames before it have been taken. The wait
        can be interrupted by a signal handler that raises (SIGINT, SIGTERM)."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            items = list(self._items)
            self._items.clear()
            if not items and self._error is not None:
                error, self._error = self._error, None
                raise error
            return items

    def feed(self, frames: Iterable[Frame], name: str = "frame-reader") -> threading.Thread:
        """Start a daemon thread that puts every frame of ``frames`` as it is read, then closes the
        queue (with the exception that stopped the iteration, if one did). A daemon: a reader
        blocked on a silent stream does not keep the process alive once the consumer stopped."""

        def read() -> None:
            try:
                for frame in frames:
                    if self._closed:
                        return
                    self.put(frame)
            except BaseException as exc:  # reported to the consumer, which decides
                self.close(exc)
            else:
                self.close()

        self.thread = threading.Thread(target=read, name=name, daemon=True)
        self.thread.start()
        return self.thread


@dataclass(frozen=True)
class LiveStep:
    """One reasoning step of a :class:`LiveLoop`.

    ``belief``: its belief (at the newest frame's ``t``); ``arrived``: arrival times (s, the queue's
    clock) of the frames observed since the previous step, this step's newest last; ``merged``: how
    many of them would have started a reasoning step of their own and were folded into this one;
    ``done``: when the step ended (same clock); ``seconds``: how long observing them and the step took.
    """

    belief: Belief
    arrived: tuple[float, ...]
    merged: int
    done: float
    seconds: float

    @property
    def latency(self) -> float:
        """s: from the arrival of the newest frame used to the end of this step."""
        return self.done - self.arrived[-1]

    @property
    def frames(self) -> int:
        """Frames observed since the previous step (this step's newest included)."""
        return len(self.arrived)


class LiveLoop:
    """Run ``estimator`` (a :class:`~estimator.filter.SceneEstimator`) on the frames of ``queue`` as
    they arrive (see the module docstring). Iterate over it for the :class:`LiveStep` of each
    reasoning step, until the stream ends; or call :meth:`poll` to process what has arrived so far
    (a caller with its own loop, or a test that decides what has arrived).

    ``on_frame(frame)``: called for every frame, before it is observed (a recorder).
    ``timeline_window`` (s of stream time): after each step the estimator's timeline forgets the
    facts and events older than this (:meth:`~estimator.timeline.Timeline.forget_before`; None: it
    keeps all). Totals: :attr:`frames`, :attr:`steps`, :attr:`merged`, :attr:`max_latency` (s),
    :attr:`busy_seconds` (time spent observing, stepping and resampling). Memory does not grow with
    the stream: frames are released once observed, the timeline holds its window.
    """

    def __init__(self, estimator, queue: FrameQueue, on_frame: Callable[[Frame], None] | None = None,
                 timeline_window: float | None = TIMELINE_WINDOW):
        if timeline_window is not None and not timeline_window >= MIN_TIMELINE_WINDOW:
            raise ValueError(f"timeline_window must be >= {MIN_TIMELINE_WINDOW} s, got {timeline_window}")
        self.estimator = estimator
        self.queue = queue
        self.on_frame = on_frame
        self.timeline_window = timeline_window
        self.horizon = estimator.config.reasoner.horizon
        self.frames = 0
        self.steps = 0
        self.merged = 0
        self.max_latency = 0.0
        self.busy_seconds = 0.0
        self._arrived: list[float] = []  # arrival times of the frames observed since the last step
        self._due = 0  # of those, frames that would have started a step of their own
        self._t_due = estimator.t_tick  # where the frame-by-frame loop would have stepped last

    @property
    def finished(self) -> bool:
        """The stream ended and every frame was taken."""
        return self.queue.finished

    def poll(self, timeout: float | None = 0.0) -> LiveStep | None:
        """Take every frame that has arrived (waiting up to ``timeout`` s for one; None: as long as
        it takes), observe them all, and run a reasoning step at the newest if one is due. Returns
        that step, or None (no frame, or no step due yet)."""
        clock = self.queue.clock
        t0 = clock()
        self.estimator.finish()  # the last step's resampling, while nothing waits for an estimate
        self.busy_seconds += clock() - t0
        batch = self.queue.take(timeout)
        if not batch:
            return None
        t0 = clock()
        est = self.estimator
        for a in batch:
            if self.on_frame is not None:
                self.on_frame(a.frame)
            est.observe(a.frame)
            self._arrived.append(a.arrived)
            if reasoning_due(self._t_due, a.frame.t, self.horizon):
                self._due += 1
                self._t_due = a.frame.t
        self.frames += len(batch)
        if not self._due:
            self.busy_seconds += clock() - t0
            return None
        belief = est.step(defer=True)  # out before the resampling, which the next poll runs
        done = clock()
        if self.timeline_window is not None:
            est.timeline.forget_before(belief.t - self.timeline_window)
        self._t_due = belief.t
        step = LiveStep(belief, tuple(self._arrived), self._due - 1, done, done - t0)
        self._arrived, self._due = [], 0
        self.steps += 1
        self.merged += step.merged
        self.max_latency = max(self.max_latency, step.latency)
        self.busy_seconds += step.seconds
        return step

    def __iter__(self):
        while not self.finished:
            step = self.poll(timeout=None)
            if step is not None:
                yield step
        self.estimator.finish()
