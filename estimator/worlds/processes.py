"""How the particle worlds' worker processes are started.

Where the platform has it (Linux, macOS), a worker is forked from multiprocessing's fork server: a
single-threaded process that has imported the worker's code (:data:`WORKER_MODULES`: numpy, pybullet,
the worlds) once. A worker then starts building within a few tens of milliseconds of the pool's
construction, where a spawned one first spends 0.3-0.4 s (two at once on two cores, measured here)
in a fresh interpreter importing that code. The server is forked from nothing but itself, so the
caller's threads (a ROS node's, a live viewer's) are never forked; it ends when the process that
started it ends. Elsewhere (Windows) workers are spawned.

:func:`start_worker_server` starts the server ahead of time, so that its imports run while the caller
does its own start-up (the command line calls it first thing for the commands that build worlds in
workers). What a worker computes does not depend on how it was started.

This module imports nothing heavy, so that calling it early costs the caller nothing.
"""
from __future__ import annotations

import multiprocessing as mp
import multiprocessing.context
import multiprocessing.forkserver

WORKER_MODULES = ("estimator.worlds.shard",)
"""What the fork server imports before it forks any worker (a worker's entry point and everything
it uses)."""


def start_method() -> str:
    """``"forkserver"`` where the platform has it, else ``"spawn"``."""
    return "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"


def worker_context() -> multiprocessing.context.BaseContext:
    """The multiprocessing context workers are started with (:func:`start_method`); with the fork
    server, its imports are :data:`WORKER_MODULES` (they take effect when the server starts: a
    server already running, started by other code, keeps its own, and workers import the rest)."""
    ctx = mp.get_context(start_method())
    if ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload(list(WORKER_MODULES))
    return ctx


def start_worker_server() -> None:
    """Start the fork server workers are forked from, if it is not running, and return without
    waiting for its imports (nothing to do where workers are spawned)."""
    if worker_context().get_start_method() == "forkserver":
        multiprocessing.forkserver.ensure_running()
