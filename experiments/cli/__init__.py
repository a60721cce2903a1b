"""The ``scene-estimator`` command line.

Subcommands: ``run`` (estimate a recorded stream), ``config`` (the configuration ``run`` would use),
``demo`` (the built-in example), ``simulate``
(scenario simulator), ``evaluate`` (statistics over scenarios, seeds and methods), ``bench`` (speed
against bare pybullet stepping), ``track`` (a Kalman pose tracker, fed back by the estimator),
``search`` (where to look first for a hidden object), ``search-eval`` (the search experiment),
``predictability`` (which scenarios allow a 5 cm answer at all), ``ros`` (a live ROS 1 node; needs
rospy).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Iterable

WORKER_COMMANDS = frozenset({"run", "bench", "track", "search", "ros"})
"""The commands whose particle worlds run in worker processes unless ``--workers 0`` (by default one
per core when there is more than one particle)."""


def _command(argv: list[str]) -> str | None:
    """The subcommand named by ``argv`` (its first word not an option: the top-level parser has no
    option but ``--help``), or None."""
    return next((a for a in argv if not a.startswith("-")), None)


def _start_worker_server(argv: list[str]) -> None:
    """For a command of :data:`WORKER_COMMANDS`, start the server its workers are forked from
    (:func:`estimator.worlds.processes.start_worker_server`) before the command's own imports, which
    it then runs beside; not with ``--workers 0`` (``--workers=0``). A command that turns out to
    have no workers (one particle) leaves the server idle; it ends with the command."""
    if _command(argv) not in WORKER_COMMANDS:
        return
    for a, b in zip(argv, argv[1:] + [""]):
        if a == "--workers=0" or (a == "--workers" and b == "0"):
            return
    from estimator.worlds.processes import start_worker_server

    start_worker_server()


COMMANDS: tuple[tuple[str, str, str, str, str], ...] = (
    ("run", "estimate a recorded observation stream", "run", "add_run_arguments", "cmd_run"),
    ("config", "print the estimator configuration (all fields) that `run` would use", "run",
     "add_config_arguments", "cmd_config"),
    ("demo", "run the built-in example", "demo", "add_demo_arguments", "run_demo"),
    ("simulate", "simulate a scenario with ground truth", "simulate", "add_simulate_arguments", "run_simulate"),
    ("evaluate", "statistical evaluation over scenarios, seeds and methods", "evaluate", "add_evaluate_arguments",
     "run_evaluate"),
    ("bench", "update time against bare pybullet stepping", "bench", "add_bench_arguments", "run_bench"),
    ("track", "Kalman pose tracker over a stream, kept alive by the estimator with --feedback", "track",
     "add_track_arguments", "run_track"),
    ("fit-priors", "fit the held-object priors (with --regions: the position regions) on simulated "
     "scenarios (seeds 100-119)", "fit", "add_fit_arguments", "run_fit"),
    ("predictability", "which scenarios let anyone say where their objects end, to 5 cm (twins moved "
     "by the tracker's noise at each object's last sighting, its parameters drawn again)", "predictability",
     "add_predictability_arguments", "run_predictability"),
    ("search", "where to look first for a hidden object: ranked places and a look plan", "search",
     "add_search_arguments", "run_search"),
    ("search-eval", "the search experiment: a simulated robot camera looks for hidden objects, by method",
     "search_eval", "add_search_eval_arguments", "run_search_eval"),
    ("ros", "a live ROS 1 node: perception topics in (as `run --bag --topics`), estimates out (TF, poses "
     "with covariance, RViz markers, the estimate line); needs rospy", "ros", "add_ros_arguments", "run_ros"))
"""Each subcommand: (name, one-line help, its module in ``experiments.cli``, the function that adds
its arguments, the function that runs it)."""


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The ``scene-estimator`` parser. Every subcommand is listed; its arguments are added, and its
    module imported, for those named in ``commands`` (default: all). ``main`` names only the one
    invoked: a command imports its own code, not all of the others'."""
    chosen = None if commands is None else set(commands)
    parser = argparse.ArgumentParser(prog="scene-estimator", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, text, module, add, run in COMMANDS:
        p_sub = sub.add_parser(name, help=text)
        if chosen is None or name in chosen:
            mod = importlib.import_module(f"experiments.cli.{module}")
            getattr(mod, add)(p_sub)
            p_sub.set_defaults(func=getattr(mod, run))
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _start_worker_server(argv)
    from experiments.streams import EXIT_SIGINT, EXIT_SIGTERM, Terminated, silence_stdout

    command = _command(argv)
    parser = build_parser([command] if command else [])
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    try:
        return args.func(args)
    except ValueError as exc:  # InputError (file, line, field) included
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: the estimates written so far are kept", file=sys.stderr)
        return EXIT_SIGINT
    except Terminated:
        print("terminated (SIGTERM): the estimates written so far are kept", file=sys.stderr)
        return EXIT_SIGTERM
    except BrokenPipeError:  # the reader of standard output went away (| head): nothing more to say
        silence_stdout()
        return 0


if __name__ == "__main__":
    sys.exit(main())
