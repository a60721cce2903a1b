"""Sweeps of trials: backends, resumable results.

A *sweep* runs every trial (:mod:`experiments.evaluation.trials`) of a :class:`SweepConfig` that is
not already in ``OUT/trials.jsonl``, on a local process pool (``backend="local"``, spawned
processes) or as Ray tasks (``backend="ray"``; ``address`` joins an existing cluster), appends one
line per finished trial (flushed at once; an interrupted sweep loses at most the trials in flight,
and a line cut in the middle is dropped on the next run), shows a progress bar (tqdm) with an ETA
on stderr, and finally writes ``summary.md``, ``summary.csv`` and PNG figures into ``OUT``
(:mod:`experiments.evaluation.report`). The per-scenario figures need a trace (estimates over time,
particle cloud) of one seed per scenario and method; traces are written to ``OUT/traces/`` by the
trials of ``SweepConfig.trace_seeds``.
"""
from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from tqdm import tqdm

from experiments.evaluation.methods import effective_particles, get_method
from experiments.evaluation.report import write_report
from experiments.evaluation.trials import TrialSpec, run_trial_safe

TRIALS_FILE = "trials.jsonl"

# --------------------------------------------------------------------------------------------------
# sweeps


class TrialFailures(RuntimeError):
    """Some trials of a sweep raised; their tracebacks are in ``errors.jsonl``."""


@dataclass(frozen=True)
class SweepConfig:
    """The trials of a sweep: every truth engine x parameter scale x scenario x seed x method, each
    particle method once per K in ``particles`` (last-seen and paper once). ``engines``: the physics
    engines of the ground truth (:data:`~experiments.simulation.simulator.ENGINES`); ``param_scales``:
    factors on the truth's frictions and restitution against the nominal values the estimator is
    given. ``trace_seeds``: seeds whose trials write traces for
    the per-scenario figures (default: the first seed). ``config``: estimator configuration data
    (canonical JSON) for the particle methods, on top of each one's own settings; last-seen and the
    paper's reasoner, the references, are left as they are."""

    scenarios: tuple[str, ...]
    seeds: tuple[int, ...]
    methods: tuple[str, ...]
    particles: tuple[int, ...] = (64,)
    duration: float | None = None
    trace_seeds: tuple[int, ...] | None = None
    config: str | None = None
    engines: tuple[str, ...] = ("bullet",)
    param_scales: tuple[float, ...] = (1.0,)

    def __post_init__(self):
        if not self.scenarios or not self.seeds or not self.methods or not self.particles:
            raise ValueError("a sweep needs at least one scenario, seed, method and particle count")
        from experiments.simulation.simulator import ENGINES
        if not self.engines or any(e not in ENGINES for e in self.engines):
            raise ValueError(f"truth engines must be among {', '.join(ENGINES)}, got {', '.join(self.engines)}")
        if not self.param_scales or any(not (0 < s < float("inf")) for s in self.param_scales):
            raise ValueError(f"parameter scales must be > 0, got {self.param_scales}")
        for m in self.methods:
            get_method(m)
        if any(k < 0 for k in self.particles):
            raise ValueError(f"particle counts must be >= 1 (or 0: auto), got {self.particles}")
        if self.duration is not None and not self.duration > 0:
            raise ValueError(f"duration must be > 0, got {self.duration}")

    def trials(self, rerun_dir: str | None = None) -> list[TrialSpec]:
        """The sweep's trials in canonical order (engine, scale, scenario, seed, method, K), without
        duplicates."""
        traces = set(self.trace_seeds if self.trace_seeds is not None else self.seeds[:1])
        out, seen = [], set()
        for engine in self.engines:
            for scale in self.param_scales:
                for sc in self.scenarios:
                    for seed in self.seeds:
                        for m in self.methods:
                            for k in self.particles:
                                cfg = self.config if get_method(m).uses_particles else None
                                spec = TrialSpec(sc, int(seed), m, effective_particles(m, k), self.duration,
                                                 trace=seed in traces, rerun_dir=rerun_dir, config=cfg,
                                                 engine=engine, param_scale=float(scale))
                                if spec.key not in seen:
                                    seen.add(spec.key)
                                    out.append(spec)
        return out


def read_rows(path: str | os.PathLike, repair: bool = False) -> list[dict]:
    """Rows of a ``trials.jsonl``. A last line cut short by an interruption is ignored (and, with
    ``repair``, removed from the file so that the next row starts on a fresh line); a malformed line
    elsewhere is an error. Later rows with the same key replace earlier ones."""
    p = Path(path)
    if not p.exists():
        return []
    data = p.read_bytes()
    lines = data.split(b"\n")
    rows: dict[str, dict] = {}
    good_end = 0
    pos = 0
    for i, line in enumerate(lines):
        end = pos + len(line) + 1
        if line.strip():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                if i < len(lines) - 1 and any(x.strip() for x in lines[i + 1:]):
                    raise ValueError(f"{p}: line {i + 1} is not valid JSON") from None
                break
            if i == len(lines) - 1:  # complete JSON but no newline: keep it, add the newline
                rows[row["key"]] = row
                good_end = len(data)
                break
            rows[row["key"]] = row
        good_end = min(end, len(data))
        pos = end
    if repair:
        with open(p, "r+b") as fh:
            fh.truncate(good_end)
            if good_end and not data[:good_end].endswith(b"\n"):
                fh.seek(0, 2)
                fh.write(b"\n")
    return list(rows.values())


def append_results(results: Iterable[dict], path: str | os.PathLike, total: int, done_before: int, progress: bool,
                   on_result: Callable[[dict], None] | None = None, allow_nan: bool = False) -> list[dict]:
    """Consume ``results`` (``{"row": row}``, or ``{"row": None, "key", "error"}`` for a trial that
    raised) as they come: append each row to ``path`` as one JSON line, flushed at once (an
    interrupted sweep keeps them), report failures on stderr, call ``on_result`` with every result,
    and show a progress bar (tqdm, stderr) over ``total`` trials of which ``done_before`` were done.
    Pending trials are cancelled when this stops (the generator is closed). Returns the failures."""
    bar = tqdm(total=total, initial=done_before, unit="trial", disable=not progress, file=sys.stderr,
               mininterval=1.0, dynamic_ncols=True)
    failures = []
    try:
        with open(path, "a", encoding="utf-8") as fh:
            for res in results:
                bar.update()
                if res["row"] is None:
                    failures.append(res)
                    bar.write(f"trial {res['key']} failed:\n{res['error']}", file=sys.stderr)
                else:
                    fh.write(json.dumps(res["row"], allow_nan=allow_nan) + "\n")
                    fh.flush()
                if on_result is not None:
                    on_result(res)
    finally:
        close = getattr(results, "close", None)
        if close is not None:
            close()
        bar.close()
    return failures


PARENT_POLL = 0.5
"""s: how often a pool's worker process checks that the process that started it is still there
(:func:`exit_with_parent`)."""


def exit_with_parent(parent: int) -> None:
    """Pool initializer: a daemon thread ends this worker process (``os._exit``) once its parent,
    process ``parent`` (pid), is gone. A parent ended by a signal it does not handle (``kill``,
    which sends SIGTERM, or SIGKILL) closes no pool, and its spawned workers went on running their
    trials, orphaned, for as long as they had trials queued. The results already written by the
    parent are kept; the trials running are lost (the same command runs them again: it skips the
    trials already in its output)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def spawn_pool(workers: int):
    """A ``multiprocessing`` pool of ``workers`` spawned processes that end with this one
    (:func:`exit_with_parent`); a context manager."""
    return multiprocessing.get_context("spawn").Pool(workers, initializer=exit_with_parent, initargs=(os.getpid(),))


def local_results(specs: list, workers: int, fn: Callable = run_trial_safe) -> Iterable[dict]:
    """Run ``fn(spec)`` for every spec (default: an evaluation trial) in this process
    (``workers <= 1``) or on a pool of spawned processes, which end with this one
    (:func:`exit_with_parent`); yields results as they finish. When the consumer stops early (closes
    this generator: an interruption, an error), pending trials are cancelled and the running ones
    ended with their workers (SIGTERM), not waited for: their results would not be written."""
    if workers <= 1:
        for spec in specs:
            yield fn(spec)
        return
    ctx = multiprocessing.get_context("spawn")
    others = {p.pid for p in multiprocessing.active_children()}  # children that are not the pool's
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=None,
                                  initializer=exit_with_parent, initargs=(os.getpid(),))
    try:
        futures = [pool.submit(fn, s) for s in specs]
        for fut in cf.as_completed(futures):
            yield fut.result()
    except BaseException:  # the consumer stopped (a signal, an error): the trials running are not waited for
        for proc in multiprocessing.active_children():
            if proc.pid not in others:  # the pool's workers
                proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _ray_results(specs: list[TrialSpec], workers: int, address: str | None,
                 init_kwargs: dict | None) -> Iterable[dict]:
    """Run trials as Ray tasks (one CPU each); yields results as they finish."""
    try:
        import ray
    except ImportError:
        raise RuntimeError("the ray backend needs Ray: pip install 'scene-estimator[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw = dict(init_kwargs or {})
        if address:
            kw["address"] = address
        else:
            kw.setdefault("num_cpus", max(workers, 1))
            kw.setdefault("include_dashboard", False)
        kw.setdefault("log_to_driver", False)
        ray.init(**kw)
        started = True
    remote = ray.remote(num_cpus=1, max_retries=1)(run_trial_safe)
    pending = [remote.remote(s) for s in specs]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                yield ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


def code_version() -> dict:
    """Git commit of the code and whether the working tree differs from it (best effort)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit or None, "dirty": bool(dirty) if commit else None}


def logged_runs(path: Path) -> list[dict]:
    """The runs logged in ``runs.jsonl`` at ``path`` (see :func:`_log_run`), oldest first; a line
    that is not JSON (cut short by an interruption) is skipped; none when there is no file."""
    if not path.exists():
        return []
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def _log_run(path: Path, config: SweepConfig, backend: str, workers: int | None, code: dict) -> None:
    """Append when, with which ``code`` (:func:`code_version`) and how a sweep was (re)started to
    ``runs.jsonl``: rows of a resumed sweep may come from several runs."""
    rec = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **code, "backend": backend,
           "workers": workers, "config": {k: (list(v) if isinstance(v, tuple) else v)
                                          for k, v in config.__dict__.items()}}
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(rec) + "\n")


def run_sweep(config: SweepConfig, out_dir: str | os.PathLike, *, backend: str = "local",
              workers: int | None = None, address: str | None = None, rerun_dir: str | None = None,
              progress: bool = True, ray_init: dict | None = None, report: bool = True,
              on_row: Callable[[dict], None] | None = None) -> list[dict]:
    """Run the trials of ``config`` missing from ``out_dir/trials.jsonl`` and write the summary.

    Args:
        backend: ``"local"`` (process pool; ``workers <= 1`` runs in this process) or ``"ray"``.
        workers: parallel trials (default: the number of CPUs; Ray: CPUs of the local cluster).
        address: Ray cluster to join (``"auto"``, ``"ray://host:10001"``...); default a local one.
        rerun_dir: record every trial there as ``<key>.rrd``.
        ray_init: extra keyword arguments of ``ray.init``.
        report: write ``summary.md``, ``summary.csv`` and the figures at the end.
        on_row: called with every newly finished row.

    Returns the rows of the sweep's trials in canonical order. Raises :class:`TrialFailures` at
    the end (after the summary of the others) when some trials raised; they are not written to
    ``trials.jsonl``, so the next run retries them.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / TRIALS_FILE
    specs = config.trials(rerun_dir)
    now = code_version()
    earlier = logged_runs(out / "runs.jsonl")
    _log_run(out / "runs.jsonl", config, backend, workers, now)
    done = {r["key"]: r for r in read_rows(path, repair=True)}
    todo = [s for s in specs if s.key not in done]
    kept = len(specs) - len(todo)
    if kept and (now["dirty"] or not earlier
                 or any(r.get("commit") != now["commit"] or r.get("dirty") for r in earlier)):
        def name(code: dict) -> str:
            return (code.get("commit") or "unknown")[:10] + (" with changes" if code.get("dirty") else "")
        print(f"note: {kept} of {len(specs)} trials are kept from {TRIALS_FILE} as earlier runs wrote them "
              f"(code {', '.join(sorted({name(r) for r in earlier})) or 'unknown'}; now {name(now)}): "
              f"delete {path} to measure the code as it is", file=sys.stderr)
    # longest first (particle trials), for a shorter tail
    todo.sort(key=lambda s: (-s.particles, s.scenario, s.seed, s.method))
    workers = workers if workers is not None else (os.cpu_count() or 1)
    failures: list[dict] = []
    if todo:
        results = (_ray_results(todo, workers, address, ray_init) if backend == "ray"
                   else local_results(todo, workers))

        def keep(res: dict) -> None:
            row = res["row"]
            if row is None:
                with open(out / "errors.jsonl", "a", encoding="utf-8") as ef:
                    ef.write(json.dumps({"key": res["key"], "error": res["error"]}) + "\n")
                return
            done[row["key"]] = row
            if res.get("trace") is not None:
                (out / "traces").mkdir(exist_ok=True)
                with open(out / "traces" / f"{row['key']}.json", "w", encoding="utf-8") as tf:
                    json.dump(res["trace"], tf)
            if on_row is not None:
                on_row(row)

        failures = append_results(results, path, len(specs), len(specs) - len(todo), progress, keep)
    rows = [done[s.key] for s in specs if s.key in done]
    if report and rows:
        write_report(rows, out)
    if failures:
        raise TrialFailures(f"{len(failures)} of {len(specs)} trial(s) failed (tracebacks in "
                            f"{out / 'errors.jsonl'}); the summary covers the others; run again to retry")
    return rows
