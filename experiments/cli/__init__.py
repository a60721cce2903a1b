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
import logging
import sys


def main(argv: list[str] | None = None) -> int:
    from experiments.streams import EXIT_SIGINT, EXIT_SIGTERM, Terminated, silence_stdout

    parser = argparse.ArgumentParser(prog="scene-estimator", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    from experiments.cli.common import add_estimator_arguments
    from experiments.cli.run import add_run_arguments, cmd_config, cmd_run

    p_run = sub.add_parser("run", help="estimate a recorded observation stream")
    add_run_arguments(p_run)
    p_run.set_defaults(func=cmd_run)
    p_cfg = sub.add_parser("config", help="print the estimator configuration (all fields) that `run` would use")
    add_estimator_arguments(p_cfg)
    p_cfg.add_argument("--json", action="store_true", help="JSON instead of YAML")
    p_cfg.set_defaults(func=cmd_config)
    from experiments.cli.demo import add_demo_arguments, run_demo

    p_demo = sub.add_parser("demo", help="run the built-in example")
    add_demo_arguments(p_demo)
    p_demo.set_defaults(func=run_demo)
    from experiments.cli.bench import add_bench_arguments, run_bench
    from experiments.cli.evaluate import add_evaluate_arguments, run_evaluate
    from experiments.cli.fit import add_fit_arguments, run_fit
    from experiments.cli.predictability import add_predictability_arguments, run_predictability
    from experiments.cli.ros import add_ros_arguments, run_ros
    from experiments.cli.search import add_search_arguments, run_search
    from experiments.cli.search_eval import add_search_eval_arguments, run_search_eval
    from experiments.cli.simulate import add_simulate_arguments, run_simulate
    from experiments.cli.track import add_track_arguments, run_track

    for name, text, add, run in [
            ("simulate", "simulate a scenario with ground truth", add_simulate_arguments, run_simulate),
            ("evaluate", "statistical evaluation over scenarios, seeds and methods", add_evaluate_arguments,
             run_evaluate),
            ("bench", "update time against bare pybullet stepping", add_bench_arguments, run_bench),
            ("track", "Kalman pose tracker over a stream, kept alive by the estimator with --feedback",
             add_track_arguments, run_track),
            ("fit-priors", "fit the held-object priors (with --regions: the position regions) on simulated "
             "scenarios (seeds 100-119)", add_fit_arguments, run_fit),
            ("predictability", "which scenarios let anyone say where their objects end, to 5 cm (twins moved "
             "by the tracker's noise at each object's last sighting, its parameters drawn again)",
             add_predictability_arguments, run_predictability),
            ("search", "where to look first for a hidden object: ranked places and a look plan",
             add_search_arguments, run_search),
            ("search-eval", "the search experiment: a simulated robot camera looks for hidden objects, by method",
             add_search_eval_arguments, run_search_eval),
            ("ros", "a live ROS 1 node: perception topics in (as `run --bag --topics`), estimates out (TF, poses "
             "with covariance, RViz markers, the estimate line); needs rospy", add_ros_arguments, run_ros)]:
        p_sub = sub.add_parser(name, help=text)
        add(p_sub)
        p_sub.set_defaults(func=run)
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
