"""``scene-estimator evaluate``: every scenario, many seeds, several methods; metrics with confidence
intervals, paired tests, plots. Resumable, on a local process pool or a Ray cluster.

The lead wires :func:`add_evaluate_arguments` and :func:`run_evaluate` into the ``scene-estimator``
console script as the ``evaluate`` subcommand::

    scene-estimator evaluate --scenarios all --seeds 30 --methods last-seen,paper,particles \\
        --particles 64 --out results/
    scene-estimator evaluate --scenarios cup_falls_behind_box --seeds 5 --particles 8,16,32,64 \\
        --methods paper,particles --out results/scaling/
    scene-estimator evaluate ... --backend ray --address auto      # join a running Ray cluster
    scene-estimator evaluate --scenarios all --seeds 20 --truth-engine bullet,mujoco \
        --methods paper,particles --out results/                     # both truth engines side by side
    scene-estimator evaluate ... --param-scale 0.5,1,2,4             # the truth's frictions scaled

Interrupted (Ctrl-C, a killed job), the same command continues where it stopped: finished trials
are read back from ``OUT/trials.jsonl`` and skipped.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from experiments.cli.common import AUTO_RANGE
from experiments.evaluation.methods import AUTO
from physics.errors import InputError


def _positive_int_list(text: str) -> tuple[int, ...]:
    """Comma-separated integers >= 1; ``auto`` (the adaptive count) is :data:`AUTO` (0)."""
    try:
        values = tuple(AUTO if v.strip().lower() == "auto" else int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers (or auto), got {text!r}") from None
    if not values or any(v < 1 and v != AUTO for v in values):
        raise argparse.ArgumentTypeError(f"expected integers >= 1 (or auto), got {text!r}")
    return values


def _estimator_config(path: str) -> str:
    """The data of an estimator configuration file as canonical JSON, checked (a bad field raises
    :class:`~physics.errors.ConfigError` with its line); ``particles`` and ``workers`` belong to the
    sweep, not to the file."""
    from estimator.config import config_from_dict, default_config, read_config_file
    from physics.errors import ConfigError

    data, lines = read_config_file(path)
    for name in ("particles", "workers", "base"):
        if isinstance(data, dict) and name in data:
            raise ConfigError("set by the sweep (--particles; trials run their worlds in their own process)",
                              path=path, line=lines.get(name), field=name)
    config_from_dict(data, path=path, lines=lines, start=default_config(64))
    return json.dumps(data or {}, sort_keys=True, separators=(",", ":"))


def add_evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``evaluate`` to ``parser``."""
    parser.add_argument("--scenarios", default="all",
                        help="'all' or comma-separated built-in scenario names (default all)")
    parser.add_argument("--seeds", type=int, default=10, help="number of seeds: 0 .. N-1 (default 10)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--methods", default="last-seen,paper,particles",
                        help="comma-separated methods (default last-seen,paper,particles); known: "
                             "last-seen, paper, particles, particles-no-params, particles-no-held, "
                             "particles-no-negative")
    parser.add_argument("--particles", type=_positive_int_list, default=(64,), metavar="K[,K...]",
                        help="particle worlds of the particle methods; several values for a scaling "
                             f"study; auto: the adaptive count, KLD-sampling, {AUTO_RANGE} (default 64)")
    parser.add_argument("--workers", type=int, default=None,
                        help="trials run in parallel (default: number of CPUs; 1: in this process)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local",
                        help="local process pool (default) or Ray tasks")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (e.g. 'auto' or 'ray://head:10001'); default: start "
                             "a local one")
    parser.add_argument("--out", default="results", metavar="DIR",
                        help="output folder: trials.jsonl, summary.md/.csv, figures (default results/)")
    parser.add_argument("--rerun-dir", default=None, metavar="DIR",
                        help="also record every trial as a rerun file DIR/<trial>.rrd")
    parser.add_argument("--duration", type=float, default=None,
                        help="seconds to simulate per scenario (default: each scenario's own)")
    parser.add_argument("--trace-seeds", type=int, default=1,
                        help="how many seeds (the first ones) keep traces for the per-scenario figures "
                             "(default 1)")
    parser.add_argument("--config", metavar="FILE", default=None,
                        help="estimator configuration file (YAML or JSON) for the particle methods, on top "
                             "of each one's own settings (K comes from --particles); last-seen and paper "
                             "are left as they are. Trials run with a file are keyed by its content.")
    parser.add_argument("--truth-engine", default="bullet", metavar="ENGINE[,ENGINE]",
                        help="physics engine(s) of the ground truth: bullet (the estimator's own engine), "
                             "mujoco, or both (bullet,mujoco: reported side by side); the estimator is never "
                             "told (default bullet)")
    parser.add_argument("--param-scale", default="1", metavar="S[,S...]",
                        help="factors on the truth's friction, rolling friction and restitution against the "
                             "nominal values the estimator's scene states, e.g. 0.5,1,2,4 (default 1)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary on stdout")


def run_evaluate(args: argparse.Namespace) -> int:
    """Run the ``evaluate`` subcommand; returns the exit code (0 ok, 1 some trials failed, 2 bad input,
    130 interrupted by SIGINT, 143 by SIGTERM; the finished trials are kept either way)."""
    from experiments.evaluation.methods import METHODS
    from experiments.evaluation.sweep import SweepConfig, TrialFailures, run_sweep
    from experiments.scenarios import resolve_scenarios
    from experiments.streams import EXIT_SIGINT, EXIT_SIGTERM, StopSignals, Terminated

    def fail(msg: str) -> int:
        print(f"scene-estimator evaluate: {msg}", file=sys.stderr)
        return 2

    try:
        scenarios = tuple(resolve_scenarios([s.strip() for s in args.scenarios.split(",") if s.strip()]))
    except InputError as exc:
        return fail(str(exc))
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        return fail(f"unknown method(s) {', '.join(unknown)} (known: {', '.join(METHODS)})")
    if args.seeds < 1 or args.first_seed < 0:
        return fail("--seeds must be >= 1 and --first-seed >= 0")
    if args.workers is not None and args.workers < 1:
        return fail("--workers must be >= 1")
    if args.address and args.backend != "ray":
        return fail("--address needs --backend ray")
    seeds = tuple(range(args.first_seed, args.first_seed + args.seeds))
    engines = tuple(e.strip() for e in args.truth_engine.split(",") if e.strip())
    try:
        scales = tuple(float(v) for v in args.param_scale.split(",") if v.strip())
    except ValueError:
        return fail(f"--param-scale: expected comma-separated numbers, got {args.param_scale!r}")
    estimator_config = None
    if args.config:
        try:
            estimator_config = _estimator_config(args.config)
        except InputError as exc:
            return fail(str(exc))
    try:
        config = SweepConfig(scenarios, seeds, methods, tuple(args.particles), args.duration,
                             trace_seeds=seeds[:max(args.trace_seeds, 0)], config=estimator_config,
                             engines=engines, param_scales=scales)
    except ValueError as exc:
        return fail(str(exc))
    if args.rerun_dir:
        try:
            from experiments import recording  # noqa: F401
        except ImportError as exc:
            return fail(f"--rerun-dir needs rerun recording support (experiments.recording): {exc}")
    n = len(config.trials())
    if not args.quiet:
        print(f"{n} trials: {len(scenarios)} scenario(s) x {len(seeds)} seed(s) x methods "
              f"{', '.join(methods)} (K = {', '.join(map(str, config.particles))}) x truth "
              f"{', '.join(engines)}" + (f" x parameter scales {', '.join(f'{v:g}' for v in scales)}"
                                         if scales != (1.0,) else "")
              + f"; backend {args.backend}; results in {args.out}/", file=sys.stderr)
    start = time.perf_counter()
    try:
        with StopSignals():  # SIGTERM (kill, systemd, a batch scheduler) ends it as Ctrl-C does
            run_sweep(config, args.out, backend=args.backend, workers=args.workers, address=args.address,
                      rerun_dir=args.rerun_dir, progress=not args.quiet)
    except (KeyboardInterrupt, Terminated) as exc:
        how = "interrupted" if isinstance(exc, KeyboardInterrupt) else "terminated (SIGTERM)"
        print(f"\n{how}: finished trials are kept in {args.out}/trials.jsonl; run the same command "
              "again to continue", file=sys.stderr)
        return EXIT_SIGINT if isinstance(exc, KeyboardInterrupt) else EXIT_SIGTERM
    except TrialFailures as exc:
        print(f"scene-estimator evaluate: {exc}", file=sys.stderr)
        return 1
    except RuntimeError as exc:  # e.g. Ray missing
        return fail(str(exc))
    if not args.quiet:
        with open(f"{args.out}/summary.md", encoding="utf-8") as fh:
            print(fh.read())
        print(f"done in {time.perf_counter() - start:.0f} s: {args.out}/summary.md, summary.csv, "
              "trials.jsonl and figures", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    """Stand-alone entry point (``python -m experiments.cli.evaluate``)."""
    parser = argparse.ArgumentParser(prog="scene-estimator evaluate", description=__doc__.splitlines()[0])
    add_evaluate_arguments(parser)
    return run_evaluate(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
