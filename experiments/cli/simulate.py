"""``scene-estimator simulate``: run a scenario and write its ground truth and synthetic perception.

The lead wires :func:`add_simulate_arguments` and :func:`run_simulate` into the ``scene-estimator``
console script as the ``simulate`` subcommand::

    scene-estimator simulate --list
    scene-estimator simulate cup_falls_behind_box --seed 3 --out runs/cup3/
    scene-estimator simulate path/to/my_scenario.yaml --duration 2
    scene-estimator simulate ball_dropped_into_box --rerun truth.rrd   # also a rerun recording
    scene-estimator simulate cup_falls_behind_box --seed 3 --engine mujoco --out runs/cup3/
"""
from __future__ import annotations

import argparse
import sys
import time

from physics.errors import InputError


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``simulate`` to ``parser``."""
    parser.add_argument("scenario", nargs="?", help="built-in scenario name or path of a scenario file")
    parser.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the randomised variant and of the perception faults (default 0)")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="output folder (default runs/<scenario>_seed<seed>/)")
    parser.add_argument("--duration", type=float, default=None,
                        help="seconds to simulate (default: the scenario's duration)")
    parser.add_argument("--engine", choices=("bullet", "mujoco"), default="bullet",
                        help="physics engine of the ground truth: bullet (the estimator's own) or mujoco "
                             "(soft contacts, another friction model; the estimator is never told) (default bullet)")
    parser.add_argument("--param-scale", type=float, default=1.0, metavar="S",
                        help="multiply the truth's frictions, rolling frictions and restitutions by S against "
                             "the nominal values the scene file states (default 1)")
    parser.add_argument("--rerun", metavar="PATH", default=None,
                        help="also write a rerun recording (.rrd) of the truth and the perception frames")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")


def run_simulate(args: argparse.Namespace) -> int:
    """Run the ``simulate`` subcommand; returns the process exit code (0 ok, 2 bad input)."""
    from experiments.scenarios import list_scenarios, load_scenario
    from experiments.simulation.simulator import simulate, write_outputs

    if args.list:
        for name in list_scenarios():
            try:
                desc = load_scenario(name).description
            except InputError as exc:  # a broken built-in file must not hide the others
                desc = f"(invalid: {exc})"
            print(f"{name:26s} {desc}")
        return 0
    if not args.scenario:
        print("scene-estimator simulate: give a scenario name or file (see --list)", file=sys.stderr)
        return 2
    if args.seed < 0:
        print("scene-estimator simulate: --seed must be >= 0", file=sys.stderr)
        return 2
    try:
        scenario = load_scenario(args.scenario)
        start = time.perf_counter()
        result = simulate(scenario, seed=args.seed, duration=args.duration, engine=args.engine,
                          param_scale=args.param_scale)
        out = args.out or f"runs/{scenario.name}_seed{args.seed}"
        paths = write_outputs(result, out)
        if getattr(args, "rerun", None):
            from experiments.recording import record_simulation

            paths["rerun"] = record_simulation(args.rerun, result.scene, result.truth, result.observations)
    except InputError as exc:
        print(f"scene-estimator simulate: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"scene-estimator simulate: cannot write output: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        elapsed = time.perf_counter() - start
        events = ", ".join(f"{e['action']} {e['subject']} at {e['t']:.2f} s" for e in result.events) or "none"
        print(f"{scenario.name} (seed {args.seed}, {args.engine}): {len(result.truth)} frames, "
              f"{result.meta['duration']:.2f} s simulated in {elapsed:.2f} s; events: {events}")
        for name, p in paths.items():
            print(f"  wrote {p}")
    return 0


def main(argv=None) -> int:
    """Stand-alone entry point (``python -m experiments.cli.simulate``)."""
    parser = argparse.ArgumentParser(prog="scene-estimator simulate", description=__doc__.splitlines()[0])
    add_simulate_arguments(parser)
    return run_simulate(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
