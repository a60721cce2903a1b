"""``scene-estimator demo``: the built-in example, the particle estimator beside the paper's reasoner.

    scene-estimator demo                      # K = 64 particle worlds, then the paper's reasoner
    scene-estimator demo --particles 32 --out demo/
    scene-estimator demo --paper              # the paper's reasoner alone (same as --particles 1)

A cup hidden behind a box falls off the table, unseen, when the box is pulled back. The demo runs
the particle estimator on the shipped stream (``experiments/data``), prints its events, facts and
final poses, then where every object ends according to each estimator: the particle estimator's
hypotheses with their probabilities, the paper's single answer, and the simulator's truth.
"""
from __future__ import annotations

import argparse
import json
import os
from importlib import resources

import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from experiments.cli.common import DEFAULT_PARTICLES, print_summary
from experiments.cli.run import run_stream


def demo_files() -> tuple[str, str]:
    """Paths of the built-in demo scene and observation stream."""
    base = resources.files("experiments.data")
    return str(base / "demo_scene.yaml"), str(base / "demo_observations.jsonl")


def demo_truth() -> dict:
    """The last line of the demo's ground truth (``experiments/data/demo_truth.jsonl``)."""
    text = (resources.files("experiments.data") / "demo_truth.jsonl").read_text(encoding="utf-8")
    return json.loads(text.splitlines()[-1])


def add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", help="folder to write estimates.jsonl and timeline.json to (and, beside "
                                      "the particle estimator's, paper_estimates.jsonl and paper_timeline.json)")
    parser.add_argument("--particles", type=int, default=DEFAULT_PARTICLES,
                        help=f"particle worlds K (default {DEFAULT_PARTICLES}; 1: the paper's reasoner alone)")
    parser.add_argument("--paper", action="store_true", help="the paper's reasoner alone (same as --particles 1)")
    parser.add_argument("--workers", type=int, default=0,
                        help="worker processes for the particle worlds (default 0: in this process)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")


def _fmt(position) -> str:
    return "[" + ", ".join(f"{v:+.3f}" for v in position) + "]"


def _where(relation: str, support: str | None) -> str:
    return f"{relation} {support or ''}".strip()


def _truth_support(truth: dict, oid: str) -> str:
    rels = {r["predicate"]: r["object"] for r in truth.get("relations", []) if r["subject"] == oid}
    for predicate in ("isIn", "isOnTop"):
        if predicate in rels:
            return _where(predicate, rels[predicate])
    return "held" if truth["objects"][oid].get("held") else "none"


def comparison_lines(particles, paper, truth: dict | None, k: int) -> list[str]:
    """Lines comparing the final :class:`~estimator.belief.Belief` of the particle estimator
    (``particles``, K = ``k``) and of the paper's reasoner (``paper``) per dynamic object, with the
    truth's line (``truth``, or ``None``)."""
    label_p, label_q, label_t = f"particle estimator (K = {k}):", "paper's reasoner:", "truth (simulator):"
    width = max(map(len, (label_p, label_q, label_t))) + 2
    lines = [f"Where each object is at t = {particles.t:.3f} s:"]
    for oid, ob in particles.objects.items():
        if not ob.hypotheses:  # static
            continue
        lines.append(f"  {oid} ({'perceived' if ob.perceived else 'hidden'})")
        for i, h in enumerate(ob.hypotheses):
            lead = label_p if i == 0 else ""
            spread = (f"  (+- {100 * np.sqrt(np.trace(ob.position_cov)):.1f} cm)" if i == 0 else "")
            lines.append(f"    {lead:<{width}}{_where(h.relation, h.support):<16} p={h.p:.2f}  at {_fmt(h.position)}"
                         + spread)
        q = paper.objects.get(oid)
        if q is not None and q.hypotheses:
            h = q.hypotheses[0]
            lines.append(f"    {label_q:<{width}}{_where(h.relation, h.support):<16} {'':6}  at {_fmt(q.position)}")
        if truth is not None and oid in truth.get("objects", {}):
            lines.append(f"    {label_t:<{width}}{_truth_support(truth, oid):<16} {'':6}  at "
                         f"{_fmt(np.asarray(truth['objects'][oid]['position']))}")
    return lines


def run_demo(args: argparse.Namespace) -> int:
    scene, obs = demo_files()
    k = 1 if args.paper else args.particles
    if k < 1:
        raise ValueError(f"--particles must be >= 1, got {k}")
    who = ("The paper's reasoner (one world, no noise) infers where it went." if k == 1
           else f"The particle estimator ({k} perturbed worlds) infers where it went;\n"
                "the paper's reasoner (one world, no noise) answers beside it at the end.")
    print("Built-in demo: a cup hidden behind a box; the box is pulled back and the cup falls off the\n"
          f"table, unseen. {who}\n")
    paths = {}
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        for name in ("estimates.jsonl", "timeline.json", "paper_estimates.jsonl", "paper_timeline.json"):
            paths[name] = os.path.join(args.out, name)
    paper_cfg = EstimatorConfig.paper()
    cfg = paper_cfg if k == 1 else EstimatorConfig(particles=k, workers=args.workers, noise=NoiseConfig())
    summary = run_stream(scene, obs, cfg, args.seed, paths.get("estimates.jsonl"), paths.get("timeline.json"))
    print_summary(summary)
    written = [paths.get("estimates.jsonl"), paths.get("timeline.json")]
    if k > 1:
        paper = run_stream(scene, obs, paper_cfg, args.seed, paths.get("paper_estimates.jsonl"),
                           paths.get("paper_timeline.json"), quiet=True)
        written += [paths.get("paper_estimates.jsonl"), paths.get("paper_timeline.json")]
        print()
        print("\n".join(comparison_lines(summary["last_belief"], paper["last_belief"], demo_truth(), k)))
    if args.out:
        print("\nwrote " + ", ".join(p for p in written if p))
    return 0
